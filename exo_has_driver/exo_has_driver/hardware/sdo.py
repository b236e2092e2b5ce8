"""A small blocking SDO client (CiA 301): expedited download, expedited and segmented upload.

Used only while the master configures the slaves at start, before the SYNC cycle runs; every
value written there fits the 4 bytes of an expedited transfer. The transport is a function
that sends one request frame to a node's SDO server and returns its answer (or None when none
came in time), so that the master keeps serving heartbeats while it waits.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from canopen.sdo.exceptions import SdoAbortedError

from exo_has_driver.errors import CanOpenError, CanOpenTimeoutError

#: Send one SDO request (8 bytes; None: send nothing) to a node and return its next answer,
#: None after ``timeout`` [s].
Exchange = Callable[[int, bytes | None, float], bytes | None]

_HEADER = struct.Struct('<BHB')
_ABORT_CODE = struct.Struct('<I')

_CS_MASK = 0xE0
_SCS_UPLOAD_INITIATE = 0x40
_SCS_DOWNLOAD_INITIATE = 0x60
_SCS_UPLOAD_SEGMENT = 0x00
_CS_ABORT = 0x80
_CCS_UPLOAD_INITIATE = 0x40
_CCS_UPLOAD_SEGMENT = 0x60
_CCS_DOWNLOAD_INITIATE = 0x20
_EXPEDITED = 0x02
_SIZE_INDICATED = 0x01
_TOGGLE = 0x10
_LAST_SEGMENT = 0x01
#: Largest answer to a segmented upload the client accepts [bytes]: names and strings.
MAX_UPLOAD = 1024


def object_name(index: int, subindex: int) -> str:
    """``'1018h sub 2'``: how the errors name an object."""
    return f'{index:04X}h sub {subindex}'


def abort_text(code: int) -> str:
    """CiA 301's description of an SDO abort code."""
    return SdoAbortedError.CODES.get(code, 'unknown abort code')


class SdoClient:
    """Blocking SDO transfers over an :data:`Exchange`.

    Parameters
    ----------
    exchange : Exchange
        The transport.
    timeout : float
        How long to wait for each answer [s].
    retries : int
        How often to repeat a request that was not answered.

    """

    def __init__(self, exchange: Exchange, timeout: float = 0.5, retries: int = 1) -> None:
        self._exchange = exchange
        self.timeout = timeout
        self.retries = retries

    def upload(self, node: int, index: int, subindex: int) -> bytes:
        """Read an object's value.

        Raises
        ------
        CanOpenTimeoutError
            If the node does not answer, naming node and object.
        CanOpenError
            On an abort or a malformed answer, naming node, object and abort code.

        """
        request = _request(_CCS_UPLOAD_INITIATE, index, subindex)
        answer = self._transfer(node, index, subindex, request, _SCS_UPLOAD_INITIATE, 'read')
        flags = answer[0]
        if flags & _EXPEDITED:
            size = 4 - ((flags >> 2) & 0x3) if flags & _SIZE_INDICATED else 4
            return bytes(answer[4:4 + size])
        return self._segments(node, index, subindex)

    def download(self, node: int, index: int, subindex: int, data: bytes) -> None:
        """Write an object's value of 1 to 4 bytes (expedited).

        Raises
        ------
        CanOpenTimeoutError, CanOpenError
            As :meth:`upload`.

        """
        if not 1 <= len(data) <= 4:
            msg = (f'node {node}: {object_name(index, subindex)}: expedited SDO writes 1 to 4 '
                   f'bytes, not {len(data)}')
            raise CanOpenError(msg)
        flags = _CCS_DOWNLOAD_INITIATE | ((4 - len(data)) << 2) | _EXPEDITED | _SIZE_INDICATED
        request = _HEADER.pack(flags, index, subindex) + bytes(data).ljust(4, b'\0')
        self._transfer(node, index, subindex, request, _SCS_DOWNLOAD_INITIATE, 'write')

    def read_unsigned(self, node: int, index: int, subindex: int) -> int:
        """Read an unsigned integer object (little endian, any size up to 4 bytes)."""
        return int.from_bytes(self.upload(node, index, subindex), 'little')

    def read_signed(self, node: int, index: int, subindex: int) -> int:
        """Read a signed integer object (little endian, any size up to 4 bytes)."""
        return int.from_bytes(self.upload(node, index, subindex), 'little', signed=True)

    def write_unsigned(self, node: int, index: int, subindex: int, value: int,
                       size: int) -> None:
        """Write an unsigned integer object of ``size`` bytes."""
        self.download(node, index, subindex, value.to_bytes(size, 'little'))

    def write_signed(self, node: int, index: int, subindex: int, value: int,
                     size: int) -> None:
        """Write a signed integer object of ``size`` bytes."""
        self.download(node, index, subindex, value.to_bytes(size, 'little', signed=True))

    def _transfer(self, node: int, index: int, subindex: int, request: bytes, expected: int,
                  what: str) -> bytes:
        """Send an initiate request; return the matching answer."""
        answer = self._ask(node, index, subindex, request, what, matching=True)
        if len(answer) != 8:
            msg = (f'node {node}: {what} {object_name(index, subindex)}: SDO answer of '
                   f'{len(answer)} bytes instead of 8')
            raise CanOpenError(msg)
        command, answered_index, answered_sub = _HEADER.unpack_from(answer)
        if command & _CS_MASK == _CS_ABORT:
            code = _ABORT_CODE.unpack_from(answer, 4)[0]
            msg = (f'node {node}: {what} {object_name(index, subindex)} aborted: 0x{code:08X} '
                   f'{abort_text(code)}')
            raise CanOpenError(msg)
        if command & _CS_MASK != expected or (answered_index, answered_sub) != (index, subindex):
            msg = (f'node {node}: {what} {object_name(index, subindex)}: unexpected SDO answer '
                   f'{answer.hex(" ")}')
            raise CanOpenError(msg)
        return answer

    def _ask(self, node: int, index: int, subindex: int, request: bytes, what: str,
             matching: bool = False) -> bytes:
        """Send a request and return the answer, retrying when none comes.

        With ``matching``, an answer for another object (a late answer to a request that was
        retried) is skipped and the wait goes on.
        """
        for _ in range(self.retries + 1):
            answer = self._exchange(node, request, self.timeout)
            while matching and answer is not None and len(answer) == 8 \
                    and _HEADER.unpack_from(answer)[1:] != (index, subindex):
                answer = self._exchange(node, None, self.timeout)
            if answer is not None:
                return answer
        msg = (f'node {node} did not answer the SDO {what} of {object_name(index, subindex)} '
               f'within {self.timeout:g} s ({self.retries + 1} tries): is it powered, on the bus '
               f'and at this node ID?')
        raise CanOpenTimeoutError(msg)

    def _segments(self, node: int, index: int, subindex: int) -> bytes:
        data = bytearray()
        toggle = 0
        while True:
            request = bytes([_CCS_UPLOAD_SEGMENT | toggle]) + bytes(7)
            answer = self._ask(node, index, subindex, request, 'read')
            command = answer[0]
            if command & _CS_MASK == _CS_ABORT:
                code = _ABORT_CODE.unpack_from(answer, 4)[0]
                msg = (f'node {node}: read {object_name(index, subindex)} aborted: '
                       f'0x{code:08X} {abort_text(code)}')
                raise CanOpenError(msg)
            if command & _CS_MASK != _SCS_UPLOAD_SEGMENT or command & _TOGGLE != toggle:
                msg = (f'node {node}: read {object_name(index, subindex)}: unexpected SDO '
                       f'segment {answer.hex(" ")}')
                raise CanOpenError(msg)
            unused = (command >> 1) & 0x7
            data += answer[1:8 - unused]
            if command & _LAST_SEGMENT:
                return bytes(data)
            if len(data) > MAX_UPLOAD:
                msg = (f'node {node}: read {object_name(index, subindex)}: more than '
                       f'{MAX_UPLOAD} bytes')
                raise CanOpenError(msg)
            toggle ^= _TOGGLE


def _request(command: int, index: int, subindex: int) -> bytes:
    return _HEADER.pack(command, index, subindex) + bytes(4)

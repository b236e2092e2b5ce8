"""The CiA 301 part of a simulated CANopen slave: dictionary, NMT, heartbeats, SDO server, EMCY.

ROS-free and free of threads: a :class:`Slave` is fed received frames and the time [s] by its
owner (:class:`exo_has_driver.devices.rig.Rig`), which serialises every call under one lock,
and sends through the ``send(cob_id, data)`` callable it was given. Subclasses add the
application (the CiA 402 drive, the sensor board) through the hooks ``_reset_application``,
``_check_write``, ``_written``, ``_refresh`` and ``_heartbeat_lost`` / ``_heartbeat_back``.

What is implemented, per CiA 301:

- the dictionary is loaded from the device's EDS (``canopen.import_od``); values are kept as
  Python ints (strings for VISIBLE_STRING) and encoded per data type on upload;
- NMT: start, stop, enter pre-operational, reset node (application and communication objects
  back to their defaults), reset communication (1000h-1FFFh only); every reset sends the
  boot-up message and ends in pre-operational. In stopped only NMT and the heartbeat work;
- heartbeat producer (1017h, ms; 0 stops it) and consumer (1016h sub 1: producer node ID in
  bits 16-23, time in ms in bits 0-15; 0 disables). Monitoring starts with the first heartbeat
  (or boot-up) of that node, as CiA 301 says; a loss is reported once and monitoring re-arms
  with the producer's next heartbeat;
- SDO server: expedited and segmented upload and download (block transfers are refused with
  abort 05040001h, which a client then retries without blocks); uploads of up to 4 bytes are
  expedited. Abort codes: 05030000h toggle bit, 05040001h command specifier, 06010002h
  read-only, 06020000h no object, 06090011h no sub-index, 06070010h/06070012h/06070013h length,
  and what the subclasses' checks raise (06090030h invalid value, 06040041h mapping);
- EMCY (COB-ID 80h + node ID): error code, error register 1001h, five zero bytes, sent in
  pre-operational and operational only;
- silence (fault injection): a silent slave neither receives nor sends anything, as if its
  cable were cut, but its timers (the heartbeat consumer) keep running.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import DeviceError, SdoAbortError

#: Directory of the EDS files (``exo_has_driver/config/canopen``, next to the package).
EDS_DIR = Path(__file__).resolve().parents[2] / 'config' / 'canopen'

#: NMT state of a slave while it boots (its boot-up message reports it).
NMT_INITIALISING = cd.NMT_BOOT_UP
NMT_STATE_NAMES = {NMT_INITIALISING: 'initialising', cd.NMT_STOPPED: 'stopped',
                   cd.NMT_OPERATIONAL: 'operational', cd.NMT_PRE_OPERATIONAL: 'pre-operational'}

# CiA 301 SDO abort codes used here.
ABORT_TOGGLE = 0x05030000
ABORT_COMMAND = 0x05040001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_LENGTH = 0x06070010
ABORT_TOO_LONG = 0x06070012
ABORT_TOO_SHORT = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_INVALID_VALUE = 0x06090030
ABORT_GENERAL = 0x08000000

# SDO command specifiers: client (request) in bits 5-7 of byte 0, server responses.
_CCS_DOWNLOAD_SEGMENT = 0
_CCS_INITIATE_DOWNLOAD = 1
_CCS_INITIATE_UPLOAD = 2
_CCS_UPLOAD_SEGMENT = 3
_CCS_ABORT = 4
_SDO_HEADER = struct.Struct('<BHB')
_SDO_ABORT = struct.Struct('<BHBI')
_EMCY = struct.Struct('<HB5x')

# Data types of CiA 301 (the EDS's DataType) the dictionaries use, as struct formats.
_FORMATS = {0x01: '<?', 0x02: '<b', 0x03: '<h', 0x04: '<i', 0x05: '<B', 0x06: '<H',
            0x07: '<I'}
_VISIBLE_STRING = 0x09

#: Error register (1001h) bit per first digit of an EMCY error code (CiA 301 table 48).
_ERROR_REGISTER_BITS = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}

Value = int | str
Send = Callable[[int, bytes], None]


def error_register_for(code: int) -> int:
    """Error register bits (1001h) that an active error with EMCY ``code`` sets."""
    if code == 0:
        return 0
    return 0x01 | _ERROR_REGISTER_BITS.get(code >> 12, 0x80)


class Slave:
    """One CANopen slave's CiA 301 services; see the module docstring.

    Parameters
    ----------
    node_id : int
        CANopen node ID, 1 to 127.
    eds : Path
        The device's EDS file.
    send : callable
        ``send(cob_id, data)``, which puts one frame on the bus.

    Raises
    ------
    DeviceError
        For a node ID out of range or an EDS that does not load.

    """

    #: Human-readable kind of the device, for messages.
    kind = 'slave'

    def __init__(self, node_id: int, eds: Path, send: Send) -> None:
        if not 1 <= node_id <= 127:
            msg = f'CANopen node ID must be 1 to 127, got {node_id}'
            raise DeviceError(msg)
        try:
            self.od = canopen.import_od(str(eds), node_id)
        except (OSError, ValueError, KeyError) as error:
            msg = f'cannot load the EDS {eds} of node {node_id}: {error}'
            raise DeviceError(msg) from error
        self.node_id = node_id
        self._send_frame = send
        self._variables: dict[tuple[int, int], ODVariable] = {}
        for obj in self.od.values():
            if isinstance(obj, ODVariable):
                self._variables[(obj.index, 0)] = obj
            elif isinstance(obj, ODRecord | ODArray):
                for sub in obj.values():
                    self._variables[(obj.index, sub.subindex)] = sub
        self.values: dict[tuple[int, int], Value] = {}
        self.nmt_state = NMT_INITIALISING
        self.silent = False
        self.heartbeat_enabled = True
        self.sent_frames = 0
        self._next_heartbeat = 0.0
        self._consumer_seen: float | None = None
        self._consumer_lost = False
        self._upload: bytes | None = None
        self._download: bytearray | None = None
        self._toggle = 0
        self._transfer = (0, 0)

    # --- dictionary ------------------------------------------------------------------------
    def _defaults(self, first: int, last: int) -> None:
        for key, var in self._variables.items():
            if first <= key[0] <= last:
                default = var.default
                if var.data_type == _VISIBLE_STRING:
                    self.values[key] = str(default or '')
                else:
                    self.values[key] = int(default or 0)

    def get(self, index: int, subindex: int = 0) -> int:
        """Return the value of a numeric object (no SDO checks; for the application, tests)."""
        value = self.values[(index, subindex)]
        if isinstance(value, str):
            msg = f'0x{index:04X}:{subindex} of node {self.node_id} is a string'
            raise DeviceError(msg)
        return value

    def encode(self, index: int, subindex: int) -> bytes:
        """Return the object's value encoded as an SDO upload sends it.

        Raises
        ------
        SdoAbortError
            For an object or sub-index the dictionary does not have.

        """
        var = self._variable(index, subindex)
        self._refresh(index)
        value = self.values[(index, subindex)]
        if isinstance(value, str):
            return value.encode('ascii', errors='replace')
        return struct.pack(_FORMATS[var.data_type or 0x07], value)

    def _variable(self, index: int, subindex: int) -> ODVariable:
        var = self._variables.get((index, subindex))
        if var is None:
            if any(key[0] == index for key in self._variables):
                msg = f'node {self.node_id}: 0x{index:04X} has no sub-index {subindex}'
                raise SdoAbortError(ABORT_NO_SUBINDEX, msg)
            msg = f'node {self.node_id}: no object 0x{index:04X}'
            raise SdoAbortError(ABORT_NO_OBJECT, msg)
        return var

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Store an SDO download after the access, length and application checks.

        Raises
        ------
        SdoAbortError
            With the CiA 301 abort code of the refusal.

        """
        var = self._variable(index, subindex)
        where = f'node {self.node_id} 0x{index:04X}:{subindex}'
        if not var.writable:
            msg = f'{where} is read-only'
            raise SdoAbortError(ABORT_READ_ONLY, msg)
        value: Value
        if var.data_type == _VISIBLE_STRING:
            value = bytes(data).decode('ascii', errors='replace')
        else:
            fmt = _FORMATS.get(var.data_type or 0)
            if fmt is None:
                msg = f'{where} has a data type this device does not write'
                raise SdoAbortError(ABORT_GENERAL, msg)
            size = struct.calcsize(fmt)
            if len(data) != size:
                code = ABORT_TOO_LONG if len(data) > size else ABORT_TOO_SHORT
                msg = f'{where} takes {size} bytes, got {len(data)}'
                raise SdoAbortError(code, msg)
            (value,) = struct.unpack(fmt, data)
            value = int(value)
        self._check_write(index, subindex, value)
        self.values[(index, subindex)] = value
        self._written(index, subindex, value)

    # --- hooks of the application ------------------------------------------------------------
    def _reset_application(self) -> None:
        """Return the application to its power-on state (objects 2000h-FFFFh are reset)."""

    def _check_write(self, index: int, subindex: int, value: Value) -> None:
        """Raise :class:`SdoAbortError` for a value the device refuses (subclasses extend it).

        The SYNC COB-ID (1005h) is fixed at 80h, and the device only consumes SYNC (bit 30,
        SYNC producer, is refused).
        """
        if index == cd.COB_ID_SYNC and value != cd.SYNC_COB_ID:
            msg = (f'node {self.node_id} 0x1005: the SYNC COB-ID is fixed at '
                   f'0x{cd.SYNC_COB_ID:X} and this device does not produce SYNC')
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        if index == cd.ERROR_BEHAVIOUR and subindex == cd.ERROR_BEHAVIOUR_COMMUNICATION_SUB \
                and value not in (cd.ERROR_BEHAVIOUR_PRE_OPERATIONAL,
                                  cd.ERROR_BEHAVIOUR_NO_CHANGE, cd.ERROR_BEHAVIOUR_STOPPED):
            msg = f'node {self.node_id} 0x1029:1: error behaviour {value} is not 0, 1 or 2'
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)

    def _written(self, index: int, subindex: int, value: Value) -> None:
        """React to a value just written by SDO."""

    def _refresh(self, index: int) -> None:
        """Bring live values (statusword, sensors) of ``index`` up to date before an upload."""

    def _update_flags(self) -> None:
        """Recompute what the PDO configuration allows, after it changed."""

    def _heartbeat_lost(self) -> None:
        """React to the loss of the consumed heartbeat (the master's)."""

    def _heartbeat_back(self) -> None:
        """React to the consumed heartbeat coming back after a loss."""

    def _left_operational(self, code: int) -> None:
        """React to leaving NMT operational (PDOs stop): ``code`` is the EMCY code of why."""

    # --- frames out ------------------------------------------------------------------------
    def send(self, cob_id: int, data: bytes) -> None:
        """Send one frame, unless the slave is silent."""
        if not self.silent:
            self.sent_frames += 1
            self._send_frame(cob_id, data)

    def send_emcy(self, code: int) -> None:
        """Send an EMCY with ``code`` and the current error register (not in stopped)."""
        if self.nmt_state in (cd.NMT_OPERATIONAL, cd.NMT_PRE_OPERATIONAL):
            self.send(cd.EMCY_BASE + self.node_id,
                      _EMCY.pack(code, self.get(cd.ERROR_REGISTER) & 0xFF))

    @property
    def pdo_active(self) -> bool:
        """Whether PDOs are exchanged: NMT operational (and not silent)."""
        return self.nmt_state == cd.NMT_OPERATIONAL and not self.silent

    # --- NMT -------------------------------------------------------------------------------
    def boot(self, now: float) -> None:
        """Power on (or reset node): every object to its default, boot-up, pre-operational."""
        self._defaults(0x0000, 0xFFFF)
        self.values[(cd.IDENTITY, 4)] = self.node_id  # a serial number per device
        self._reset_application()
        self._reset_communication(now)

    def _reset_communication(self, now: float) -> None:
        self._defaults(0x1000, 0x1FFF)
        self.values[(cd.IDENTITY, 4)] = self.node_id
        self.values[(cd.ERROR_REGISTER, 0)] = 0
        self._consumer_seen = None
        self._consumer_lost = False
        self._upload = None
        self._download = None
        self.nmt_state = NMT_INITIALISING
        self.send(cd.HEARTBEAT_BASE + self.node_id, b'\x00')  # boot-up
        self.nmt_state = cd.NMT_PRE_OPERATIONAL
        self._next_heartbeat = now + self.get(cd.PRODUCER_HEARTBEAT_TIME) * 1e-3
        self._update_flags()

    def on_nmt(self, data: bytes, now: float) -> None:
        """Handle an NMT command frame (COB-ID 0)."""
        if self.silent or len(data) < 2 or data[1] not in (0, self.node_id):
            return
        command = data[0]
        leaving = {cd.NMT_STOP: cd.NMT_STOPPED, cd.NMT_ENTER_PRE_OPERATIONAL:
                   cd.NMT_PRE_OPERATIONAL, cd.NMT_RESET_COMMUNICATION: NMT_INITIALISING}
        if self.nmt_state == cd.NMT_OPERATIONAL and command in leaving:
            # Before the state changes: the application may still send its EMCY.
            self._left_operational(cd.ERROR_COMMUNICATION)
        if command == cd.NMT_START:
            self.nmt_state = cd.NMT_OPERATIONAL
        elif command == cd.NMT_STOP:
            self.nmt_state = cd.NMT_STOPPED
        elif command == cd.NMT_ENTER_PRE_OPERATIONAL:
            self.nmt_state = cd.NMT_PRE_OPERATIONAL
        elif command == cd.NMT_RESET_NODE:
            self.boot(now)
        elif command == cd.NMT_RESET_COMMUNICATION:
            self._reset_communication(now)

    # --- heartbeats ------------------------------------------------------------------------
    def on_heartbeat(self, node_id: int, now: float) -> None:
        """Take a heartbeat (or boot-up) of ``node_id``; only the consumed producer counts."""
        if self.silent:
            return
        consumer = self.get(cd.CONSUMER_HEARTBEAT_TIME, 1)
        if (consumer >> 16) & 0x7F != node_id or consumer & 0xFFFF == 0:
            return
        self._consumer_seen = now
        if self._consumer_lost:
            self._consumer_lost = False
            self._heartbeat_back()

    def poll(self, now: float) -> None:
        """Run the timers: heartbeat production and the consumer's timeout."""
        period = self.get(cd.PRODUCER_HEARTBEAT_TIME) * 1e-3
        if period > 0.0 and now >= self._next_heartbeat:
            if self.heartbeat_enabled:
                self.send(cd.HEARTBEAT_BASE + self.node_id, bytes((self.nmt_state,)))
            # Keep the phase; after a stall, restart from now instead of sending a burst.
            self._next_heartbeat += period
            if self._next_heartbeat <= now:
                self._next_heartbeat = now + period
        consumer = self.get(cd.CONSUMER_HEARTBEAT_TIME, 1)
        timeout = (consumer & 0xFFFF) * 1e-3
        if (self._consumer_seen is not None and timeout > 0.0
                and now - self._consumer_seen > timeout):
            self._consumer_seen = None
            self._consumer_lost = True
            self._heartbeat_lost()
            self._communication_error(cd.ERROR_HEARTBEAT_LOST)

    def _communication_error(self, code: int) -> None:
        """Apply the error behaviour 1029h sub 1 (if the device has it) to the NMT state."""
        behaviour = self.values.get((cd.ERROR_BEHAVIOUR, cd.ERROR_BEHAVIOUR_COMMUNICATION_SUB))
        if self.nmt_state != cd.NMT_OPERATIONAL or behaviour is None \
                or behaviour == cd.ERROR_BEHAVIOUR_NO_CHANGE:
            return
        self._left_operational(code)
        self.nmt_state = cd.NMT_STOPPED if behaviour == cd.ERROR_BEHAVIOUR_STOPPED \
            else cd.NMT_PRE_OPERATIONAL

    @property
    def consumer_lost(self) -> bool:
        """Whether the consumed heartbeat was lost and has not come back."""
        return self._consumer_lost

    # --- SDO server ------------------------------------------------------------------------
    def on_sdo(self, data: bytes) -> None:
        """Serve one SDO request (COB-ID 600h + node ID); answer on 580h + node ID."""
        if self.silent or self.nmt_state == cd.NMT_STOPPED or len(data) != 8:
            return
        ccs = data[0] >> 5
        try:
            if ccs == _CCS_INITIATE_UPLOAD:
                self._initiate_upload(data)
            elif ccs == _CCS_UPLOAD_SEGMENT:
                self._upload_segment(data)
            elif ccs == _CCS_INITIATE_DOWNLOAD:
                self._initiate_download(data)
            elif ccs == _CCS_DOWNLOAD_SEGMENT:
                self._download_segment(data)
            elif ccs == _CCS_ABORT:
                self._upload = None
                self._download = None
            else:
                _, index, subindex = _SDO_HEADER.unpack_from(data)
                self._transfer = (index, subindex)
                msg = f'node {self.node_id}: SDO command specifier {ccs} not supported'
                raise SdoAbortError(ABORT_COMMAND, msg)
        except SdoAbortError as abort:
            self._upload = None
            self._download = None
            index, subindex = self._transfer
            self.send(cd.SDO_TX_BASE + self.node_id,
                      _SDO_ABORT.pack(0x80, index, subindex, abort.code))

    def _initiate_upload(self, data: bytes) -> None:
        _, index, subindex = _SDO_HEADER.unpack_from(data)
        self._transfer = (index, subindex)
        self._download = None
        payload = self.encode(index, subindex)
        response = bytearray(8)
        _SDO_HEADER.pack_into(response, 0, 0, index, subindex)
        if len(payload) <= 4:
            # scs 2, expedited, size indicated, n = unused bytes
            response[0] = 0x43 | ((4 - len(payload)) << 2)
            response[4:4 + len(payload)] = payload
            self._upload = None
        else:
            response[0] = 0x41  # scs 2, segmented, size indicated
            struct.pack_into('<I', response, 4, len(payload))
            self._upload = payload
            self._toggle = 0
        self.send(cd.SDO_TX_BASE + self.node_id, bytes(response))

    def _upload_segment(self, data: bytes) -> None:
        if self._upload is None:
            msg = f'node {self.node_id}: upload segment requested with no upload in progress'
            raise SdoAbortError(ABORT_COMMAND, msg)
        toggle = data[0] & 0x10
        if toggle != self._toggle:
            msg = f'node {self.node_id}: SDO upload toggle bit not alternated'
            raise SdoAbortError(ABORT_TOGGLE, msg)
        chunk, self._upload = self._upload[:7], self._upload[7:]
        last = not self._upload
        response = bytearray(8)
        response[0] = toggle | ((7 - len(chunk)) << 1) | int(last)  # scs 0
        response[1:1 + len(chunk)] = chunk
        self._toggle ^= 0x10
        if last:
            self._upload = None
        self.send(cd.SDO_TX_BASE + self.node_id, bytes(response))

    def _initiate_download(self, data: bytes) -> None:
        command, index, subindex = _SDO_HEADER.unpack_from(data)
        self._transfer = (index, subindex)
        self._upload = None
        self._variable(index, subindex)  # aborts now for a missing object
        if command & 0x02:  # expedited
            size = 4 - ((command >> 2) & 0x3) if command & 0x01 else None
            if size is None:
                # No size indicated: the object's own size, at most the four data bytes.
                fmt = _FORMATS.get(self._variable(index, subindex).data_type or 0)
                size = struct.calcsize(fmt) if fmt else 4
            self.write(index, subindex, bytes(data[4:4 + size]))
            self._download = None
        else:
            self._download = bytearray()
            self._toggle = 0
        response = bytearray(8)
        _SDO_HEADER.pack_into(response, 0, 0x60, index, subindex)
        self.send(cd.SDO_TX_BASE + self.node_id, bytes(response))

    def _download_segment(self, data: bytes) -> None:
        if self._download is None:
            msg = f'node {self.node_id}: download segment with no download in progress'
            raise SdoAbortError(ABORT_COMMAND, msg)
        command = data[0]
        toggle = command & 0x10
        if toggle != self._toggle:
            msg = f'node {self.node_id}: SDO download toggle bit not alternated'
            raise SdoAbortError(ABORT_TOGGLE, msg)
        self._download.extend(data[1:8 - ((command >> 1) & 0x7)])
        if command & 0x01:  # last segment: store, or abort before confirming it
            payload, self._download = bytes(self._download), None
            self.write(*self._transfer, payload)
        self._toggle ^= 0x10
        self.send(cd.SDO_TX_BASE + self.node_id, bytes((0x20 | toggle, 0, 0, 0, 0, 0, 0, 0)))

    # --- the fixed PDO configuration, shared by both devices ------------------------------------
    def _check_pdo_write(self, index: int, subindex: int, value: Value,
                         mappings: dict[int, tuple[tuple[int, int, int], ...]],
                         cob_ids: dict[int, int]) -> None:
        """Refuse a change of the fixed PDO configuration; accept rewriting it as it is.

        Mapping (16xxh/1Axxh): sub 0 may be 0 (the PDO is off while it is remapped) or the
        fixed count, every entry its fixed value. Communication (14xxh/18xxh): the COB-ID
        with bit 31 (PDO valid/invalid) either way, transmission type 1 (synchronous),
        inhibit time and event timer 0.

        Raises
        ------
        SdoAbortError
            06040041h for a different mapped object, 06090030h for any other change.

        """
        where = f'node {self.node_id} 0x{index:04X}:{subindex}'
        if not isinstance(value, int):
            msg = f'{where}: a PDO parameter is a number, not {value!r}'
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        if index in mappings:
            layout = mappings[index]
            if subindex == 0:
                if value not in (0, len(layout)):
                    msg = f'{where}: the mapping is fixed at {len(layout)} objects, not {value}'
                    raise SdoAbortError(ABORT_INVALID_VALUE, msg)
                return
            obj, sub, bits = layout[subindex - 1]
            expected = (obj << 16) | (sub << 8) | bits
            if value != expected:
                msg = (f'{where}: the mapping is fixed, entry {subindex} is 0x{expected:08X}, '
                       f'not 0x{value:08X}')
                raise SdoAbortError(ABORT_NOT_MAPPABLE, msg)
        elif index in cob_ids:
            # Bits 31 (PDO not valid) and 30 (no RTR) are free; the identifier is fixed.
            if subindex == 1 and value & ~(cd.PDO_COB_ID_INVALID | cd.PDO_COB_ID_NO_RTR) \
                    != cob_ids[index]:
                msg = f'{where}: the COB-ID is fixed at 0x{cob_ids[index]:X}, not 0x{value:X}'
                raise SdoAbortError(ABORT_INVALID_VALUE, msg)
            if subindex == 2 and value != 1:
                msg = f'{where}: only transmission type 1 (synchronous) is supported'
                raise SdoAbortError(ABORT_INVALID_VALUE, msg)
            if subindex in (3, 5) and value != 0:
                msg = f'{where}: inhibit time and event timer are not supported (0 only)'
                raise SdoAbortError(ABORT_INVALID_VALUE, msg)

    def pdo_enabled(self, communication: int, mapping: int) -> bool:
        """Whether a PDO is valid: COB-ID bit 31 clear and a mapping in place."""
        return (not self.get(communication, 1) & cd.PDO_COB_ID_INVALID
                and self.get(mapping, 0) != 0)

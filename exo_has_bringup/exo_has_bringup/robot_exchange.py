"""Unix datagram sockets between the robot loop and its bridge: neither end ever waits.

Free of ROS. Each end binds a socket of its own in one directory (:data:`LOOP_SOCKET`,
:data:`BRIDGE_SOCKET`) and sends to the other's. A send never blocks (``MSG_DONTWAIT``): when
the peer is not there or its queue is full the datagram is dropped and counted
(:attr:`DatagramExchange.dropped`), so that a bridge that is late, stalled or dead cannot make
the loop late. :meth:`DatagramExchange.receive` takes what has arrived, at most
:data:`RECEIVE_MAX` datagrams (a flooding peer cannot hold the loop up), and never waits;
datagrams that are not messages of :mod:`.robot_messages`, or not of the kinds this end takes,
are counted (:attr:`DatagramExchange.malformed`) with the last problem kept, never raised.
Datagrams keep their boundaries and order on a Unix socket, and are not lost in transit: only
a full queue loses them, at the sender, which counts them.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
from collections.abc import Collection
from pathlib import Path

from exo_has_bringup.errors import BringupError
from exo_has_bringup.robot_messages import (
    MAX_DATAGRAM,
    Kind,
    MalformedDatagramError,
    Message,
    decode,
    encode,
    kind_of,
)

#: The loop's socket in the exchange directory.
LOOP_SOCKET = 'loop.sock'
#: The bridge's socket in the exchange directory.
BRIDGE_SOCKET = 'bridge.sock'
#: Datagrams taken at most by one receive.
RECEIVE_MAX = 64
#: What each end takes.
LOOP_TAKES = frozenset({Kind.REFERENCE, Kind.RESET, Kind.BRIDGE_STATUS, Kind.GAINS,
                        Kind.LIFECYCLE, Kind.CONDITIONS})
BRIDGE_TAKES = frozenset({Kind.STATES, Kind.EVENT, Kind.METRICS, Kind.LOOP_STATE})
#: Longest socket path Linux takes (sun_path is 108 bytes with its terminating zero).
MAX_PATH = 107


class ExchangeError(BringupError):
    """A socket of the exchange that cannot be made (the message names the path)."""


def default_directory() -> Path:
    """Return where the sockets go by default: ``$XDG_RUNTIME_DIR/exo_has`` or ``/tmp``."""
    runtime = os.environ.get('XDG_RUNTIME_DIR')
    base = Path(runtime) if runtime else Path('/tmp')
    return base / f'exo_has-robot-{os.getuid()}'


class DatagramExchange:
    """One end of the exchange: its own bound socket and the peer's path.

    Parameters
    ----------
    own : Path
        This end's socket path; a stale socket left there is replaced.
    peer : Path
        The other end's socket path (it need not exist yet).
    takes : Collection[Kind]
        The message kinds this end accepts; others count as malformed.

    Raises
    ------
    ExchangeError
        If the socket cannot be bound (a path too long, a directory that cannot be made).

    """

    def __init__(self, own: Path, peer: Path, takes: Collection[Kind]) -> None:
        for path in (own, peer):
            if len(os.fsencode(path)) > MAX_PATH:
                msg = f'socket path {path} is longer than {MAX_PATH} bytes: choose a shorter one'
                raise ExchangeError(msg)
        self.own = own
        self.peer = str(peer)
        self._takes = frozenset(takes)
        self.sent = 0
        self.dropped = 0
        self.received = 0
        self.malformed = 0
        #: The last refused datagram's problem, empty if none.
        self.problem = ''
        self._sequence = 0
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            own.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileNotFoundError):
                own.unlink()  # a socket left by an end that was killed
            self._socket.bind(str(own))
        except OSError as exc:
            self._socket.close()
            msg = f'cannot bind the exchange socket {own}: {exc}'
            raise ExchangeError(msg) from exc
        self._socket.setblocking(False)

    def send(self, message: Message) -> bool:
        """Send a message without waiting; return whether it went (else it is counted dropped).

        Raises
        ------
        MalformedDatagramError
            For a message that cannot be encoded (an unknown joint): a bug of the caller.

        """
        data = encode(message, self._sequence)
        self._sequence = (self._sequence + 1) & 0xFFFFFFFF
        try:
            self._socket.sendto(data, socket.MSG_DONTWAIT, self.peer)
        except OSError:  # no peer (ENOENT, ECONNREFUSED) or its queue full (EAGAIN)
            self.dropped += 1
            return False
        self.sent += 1
        return True

    def wait(self, timeout: float) -> bool:
        """Wait up to ``timeout`` [s] for a datagram; return whether one is there.

        For a reader of its own (the bridge's thread); the loop never waits.
        """
        try:
            ready, _, _ = select.select([self._socket], [], [], timeout)
        except (OSError, ValueError):  # closed meanwhile
            return False
        return bool(ready)

    def receive(self) -> list[Message]:
        """Take the messages that arrived, oldest first, without waiting."""
        messages: list[Message] = []
        for _ in range(RECEIVE_MAX):
            try:
                data = self._socket.recv(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                self.malformed += 1
                self.problem = f'receiving failed: {exc}'
                break
            self.received += 1
            try:
                message = decode(data)
            except MalformedDatagramError as exc:
                self.malformed += 1
                self.problem = str(exc)
                continue
            kind = kind_of(message)
            if kind not in self._takes:
                self.malformed += 1
                self.problem = f'a {kind.name} message, which this end does not take'
                continue
            messages.append(message)
        return messages

    def close(self) -> None:
        """Close the socket and remove its path."""
        self._socket.close()
        with contextlib.suppress(FileNotFoundError):
            self.own.unlink()


def loop_end(directory: Path) -> DatagramExchange:
    """Return the loop's end of the exchange in ``directory``."""
    return DatagramExchange(directory / LOOP_SOCKET, directory / BRIDGE_SOCKET, LOOP_TAKES)


def bridge_end(directory: Path) -> DatagramExchange:
    """Return the bridge's end of the exchange in ``directory``."""
    return DatagramExchange(directory / BRIDGE_SOCKET, directory / LOOP_SOCKET, BRIDGE_TAKES)

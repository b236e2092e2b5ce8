"""Opening the CAN bus, and reading the bus faults that python-can reports.

:func:`open_bus` turns python-can's many failure modes (unknown interface, missing library,
absent channel, a SocketCAN link that is down) into one :class:`CanBusError` naming the
interface and channel. :func:`error_frame_fault` reads a SocketCAN error frame (the kernel's
``linux/can/error.h`` flags), :func:`bus_state_fault` the bus state of interfaces that report it.
"""

from __future__ import annotations

import random
import socket

import can

from exo_has_driver.errors import CanBusError, HardwareConfigError

#: Interfaces the driver is used with: the robot, tests across processes, tests in a process.
KNOWN_INTERFACES = ('socketcan', 'udp_multicast', 'virtual')

# linux/in.h and linux/in6.h: whether a socket receives every joined group's datagrams.
_IP_MULTICAST_ALL = 49
_IPV6_MULTICAST_ALL = 29
# linux/can/error.h: error class bits of an error frame's CAN ID and details in its data.
_CAN_ERR_TX_TIMEOUT = 0x0001
_CAN_ERR_CRTL = 0x0004
_CAN_ERR_BUSOFF = 0x0040
_CAN_ERR_CRTL_RX_PASSIVE = 0x10
_CAN_ERR_CRTL_TX_PASSIVE = 0x20


def open_bus(interface: str, channel: str, bitrate: int) -> can.BusABC:
    """Open a python-can bus.

    Parameters
    ----------
    interface : str
        python-can interface name: ``socketcan`` on the robot, ``udp_multicast`` between
        processes, ``virtual`` within one.
    channel : str
        ``can0``, a multicast group such as ``239.74.163.2``, or a virtual channel name.
    bitrate : int
        Bit rate [bit/s]; passed to the interfaces that set it (not SocketCAN, whose link is
        configured with ``ip link``, nor the simulated ones).

    Raises
    ------
    HardwareConfigError
        For an empty channel or a bit rate that is not positive.
    CanBusError
        If python-can cannot open it, naming interface, channel and python-can's reason.

    """
    if not channel:
        msg = f'the CAN channel is empty (interface {interface!r}): give one, e.g. can0'
        raise HardwareConfigError(msg)
    if isinstance(bitrate, bool) or not isinstance(bitrate, int) or bitrate <= 0:
        msg = f'the CAN bit rate {bitrate!r} must be a positive integer [bit/s]'
        raise HardwareConfigError(msg)
    try:
        if interface not in KNOWN_INTERFACES:
            return can.Bus(interface=interface, channel=channel, bitrate=bitrate)
        bus = can.Bus(interface=interface, channel=channel)
        if interface == 'udp_multicast':
            isolate_multicast(bus)
        return bus
    except can.CanInterfaceNotImplementedError as exc:
        msg = (f'CAN interface {interface!r} is not available ({exc}); the driver is used with '
               f'{", ".join(KNOWN_INTERFACES)}')
        raise CanBusError(msg) from exc
    except (can.CanError, OSError, ValueError) as exc:
        msg = f'cannot open CAN interface {interface!r} channel {channel!r}: {exc}'
        raise CanBusError(msg) from exc


def isolate_multicast(bus: can.BusABC) -> bool:
    """Make a ``udp_multicast`` bus receive its own multicast group only; return if it applied.

    python-can binds every udp_multicast socket to the same port on all addresses, and Linux
    then delivers to it the datagrams of every group that any socket of the machine joined
    (``IP_MULTICAST_ALL``, on by default): two buses on different groups would hear each other.
    Clearing the option keeps a bus to its group; where the platform lacks it, nothing changes.
    It reaches python-can's socket through private attributes, hence the defensive lookup.
    """
    sock = getattr(getattr(bus, '_multicast', None), '_socket', None)
    if not isinstance(sock, socket.socket):
        return False
    try:
        if sock.family == socket.AF_INET6:
            sock.setsockopt(socket.IPPROTO_IPV6, _IPV6_MULTICAST_ALL, 0)
        else:
            sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
    except OSError:
        return False
    return True


def random_multicast_group() -> str:
    """Draw a multicast group in 239.74.0.0/16 (site-local) for a udp_multicast bus of its own.

    Tests, benchmarks and sessions on one machine each take one, so that their simulated
    buses stay apart (with :func:`isolate_multicast`).
    """
    draw = random.SystemRandom()
    return f'239.74.{draw.randint(0, 255)}.{draw.randint(1, 254)}'


def error_frame_fault(message: can.Message) -> str | None:
    """Describe the bus fault an error frame reports (bus-off, error passive), or None.

    Bus errors and warnings that the controller recovers from by itself are not faults.
    """
    if not message.is_error_frame:
        return None
    flags = message.arbitration_id
    if flags & _CAN_ERR_BUSOFF:
        return 'the CAN controller went bus-off'
    if flags & _CAN_ERR_CRTL and len(message.data) > 1 and \
            message.data[1] & (_CAN_ERR_CRTL_RX_PASSIVE | _CAN_ERR_CRTL_TX_PASSIVE):
        return f'the CAN controller is error passive (error frame data 0x{message.data[1]:02X})'
    if flags & _CAN_ERR_TX_TIMEOUT:
        return 'a CAN transmission timed out (no acknowledgement)'
    return None


def bus_state_fault(bus: can.BusABC) -> str | None:
    """Describe a bus state other than error active, or None; None if the bus cannot tell."""
    try:
        state = bus.state
    except (NotImplementedError, can.CanError):
        return None
    if state is can.BusState.ERROR:
        return 'the CAN bus is in the error state (bus-off)'
    if state is can.BusState.PASSIVE:
        return 'the CAN bus is error passive'
    return None

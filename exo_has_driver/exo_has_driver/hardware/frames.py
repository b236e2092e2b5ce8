"""The master's CANopen frames, built and read as pure functions (CiA 301, can_dictionary's PDOs).

Out: NMT commands, the SYNC, the master's heartbeat, a drive's RPDO1 and SDO requests, all in
the base frame format. In: a heartbeat's NMT state, an EMCY's error code and register, and the
values of each TPDO; a frame too short, a PDO of another length than its mapping or an EMCY of
code 0 (a fault cleared) reads as None, and the master ignores it. Also the texts that name NMT
states and error codes.
"""

from __future__ import annotations

import can

from exo_has_driver import can_dictionary as cd

_NMT_STATE_NAMES = {cd.NMT_BOOT_UP: 'boot-up', cd.NMT_STOPPED: 'stopped',
                    cd.NMT_OPERATIONAL: 'operational',
                    cd.NMT_PRE_OPERATIONAL: 'pre-operational'}


def frame(cob_id: int, data: bytes | bytearray) -> can.Message:
    """Return a base-format data frame."""
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


def nmt(command: int, node: int) -> can.Message:
    """Return an NMT command (``cd.NMT_START``...) to a node (0: every node)."""
    return frame(cd.NMT_COB_ID, bytes((command, node)))


def sync() -> can.Message:
    """Return the SYNC (no counter)."""
    return frame(cd.SYNC_COB_ID, b'')


def heartbeat(node: int, state: int = cd.NMT_OPERATIONAL) -> can.Message:
    """Return a node's heartbeat reporting an NMT state."""
    return frame(cd.HEARTBEAT_BASE + node, bytes((state,)))


def rpdo1(node: int) -> can.Message:
    """Return a drive's RPDO1 (controlword, target velocity), zeroed, for :func:`pack_rpdo1`."""
    return frame(cd.RPDO1_BASE + node, bytearray(cd.DRIVE_RPDO1.size))


def pack_rpdo1(message: can.Message, controlword: int, target: int) -> None:
    """Write a controlword and a target velocity [drive units] into an RPDO1 in place."""
    cd.DRIVE_RPDO1.pack_into(message.data, 0, controlword, target)


def sdo_request(node: int, request: bytes) -> can.Message:
    """Return an SDO request to a node's server."""
    return frame(cd.SDO_RX_BASE + node, request)


def heartbeat_state(data: bytes | bytearray) -> int | None:
    """Return the NMT state a heartbeat (or boot-up) reports, None for an empty frame."""
    if not data:
        return None
    return data[0] & 0x7F  # bit 7: node guarding's toggle, reserved in a heartbeat


def emcy(data: bytes | bytearray) -> tuple[int, int] | None:
    """Return an EMCY's error code and error register; None if short or a code of 0.

    Code 0 is "error reset or no error": a fault was cleared, nothing to report.
    """
    if len(data) < 3:
        return None
    code = data[0] | (data[1] << 8)
    if code == 0:
        return None
    return code, data[2]


def drive_tpdo1(data: bytes | bytearray) -> tuple[int, int, int] | None:
    """Return a drive TPDO1's statusword, velocity and current [drive units]."""
    if len(data) != cd.DRIVE_TPDO1.size:
        return None
    status, velocity, current = cd.DRIVE_TPDO1.unpack(data)
    return status, velocity, current


def sensor_tpdo1(data: bytes | bytearray) -> tuple[int, int, int] | None:
    """Return a sensor board TPDO1's position and pressures A and B [board units]."""
    if len(data) != cd.SENSOR_TPDO1.size:
        return None
    position, pressure_a, pressure_b = cd.SENSOR_TPDO1.unpack(data)
    return position, pressure_a, pressure_b


def sensor_tpdo2(data: bytes | bytearray) -> tuple[int, int, int] | None:
    """Return a sensor board TPDO2's velocity [board units], status bits and sample counter."""
    if len(data) != cd.SENSOR_TPDO2.size:
        return None
    velocity, status, counter = cd.SENSOR_TPDO2.unpack(data)
    return velocity, status, counter


def nmt_name(state: int | None) -> str:
    """Name an NMT state a heartbeat reported; None: no heartbeat came."""
    if state is None:
        return 'none (no heartbeat)'
    return _NMT_STATE_NAMES.get(state, f'0x{state:02X}')


def fault_text(code: int | None) -> str:
    """Describe a drive's error code; None: no EMCY since it entered fault."""
    if code is None:
        return 'no EMCY received since it entered fault'
    return f'error code 0x{code:04X} {cd.ERROR_CODES.get(code, "unknown error")}'

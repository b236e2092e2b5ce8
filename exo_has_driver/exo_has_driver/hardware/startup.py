"""Start-up of the slaves over NMT and SDO, on the caller's thread before the I/O thread runs.

:func:`start_slaves`: NMT reset communication of every slave, each boot-up awaited; the SDO
configuration of each (:func:`configure_common`: identity 1018h, device type 1000h and COB-ID
SYNC 1005h checked, cycle period and heartbeat times written; on a drive, :func:`configure_drive`,
first 6007h and 1029h (:data:`ABORT_CONNECTION_OPTION`, :data:`ERROR_BEHAVIOUR`), then profile
velocity mode, quick stop option code 2 and the ramps; each PDO checked and rewritten where it
differs, :func:`configure_pdo`; last a drive's statusword and error code 603Fh); NMT start, each
heartbeat awaited to report operational. Every wait is bounded, and its error names what it
waited for (the slaves, or the node and object). Frames go through the master's :class:`Link`,
so that the master's heartbeat goes on while start-up waits.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import CanOpenError, CanOpenTimeoutError
from exo_has_driver.hardware import cia402, frames
from exo_has_driver.hardware.config import MasterConfig
from exo_has_driver.hardware.records import JointRecord
from exo_has_driver.hardware.sdo import Exchange, SdoClient, object_name

#: Error codes of a drive fault that start-up clears by itself: the master's heartbeat lost
#: (the previous master's, or this one's before it started).
AUTO_RESET_CODES = frozenset({cd.ERROR_HEARTBEAT_LOST})
#: Abort connection option code 6007h written to every drive: on a lost master heartbeat or
#: leaving NMT operational the drive quick stops (brakes on 6085h within 14 ms at full speed,
#: then switch on disabled with 605Ah = 2) rather than coasting (2) or a fault reaction (1,
#: which on a COPLEY disables the motor at once): the HAS then falls to free mode standing.
ABORT_CONNECTION_OPTION = cd.ABORT_CONNECTION_QUICK_STOP
#: Error behaviour 1029h sub 1 written to every drive: a communication error leaves the NMT
#: state alone (not pre-operational, CiA 301's default), so that once the bus is back the
#: master's RPDOs (quick stop, disable voltage) apply at once; 6007h stops the motor meanwhile.
ERROR_BEHAVIOUR = cd.ERROR_BEHAVIOUR_NO_CHANGE

_DRIVE_PDOS = ((cd.RPDO1_COMMUNICATION, cd.RPDO1_MAPPING, cd.RPDO1_BASE, cd.DRIVE_RPDO1_MAP),
               (cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING, cd.TPDO1_BASE, cd.DRIVE_TPDO1_MAP))
_SENSOR_PDOS = ((cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING, cd.TPDO1_BASE, cd.SENSOR_TPDO1_MAP),
                (cd.TPDO2_COMMUNICATION, cd.TPDO2_MAPPING, cd.TPDO2_BASE, cd.SENSOR_TPDO2_MAP))


@dataclass(frozen=True)
class Link:
    """The master's frames in and out, as start-up uses them.

    Attributes
    ----------
    send_nmt : callable
        Send an NMT command to a node: ``send_nmt(command, node)``.
    pump : callable
        Receive and handle frames, producing the master's heartbeat, until ``done()`` or
        ``timeout`` [s]: ``pump(timeout, done)``.
    exchange : Exchange
        The SDO client's transport.

    """

    send_nmt: Callable[[int, int], None]
    pump: Callable[[float, Callable[[], bool]], None]
    exchange: Exchange


def start_slaves(link: Link, config: MasterConfig,
                 joints: Sequence[JointRecord]) -> list[JointRecord]:
    """Reset, configure and start every joint's slaves; return the joints to fault reset.

    Those are the joints whose drive is in a fault start-up may clear (:data:`AUTO_RESET_CODES`).
    The slaves' heartbeats, which the master's frame handlers record, tell when they booted and
    when they are operational.

    Raises
    ------
    CanOpenTimeoutError
        If a slave does not boot, answer an SDO or report operational in time, naming it.
    CanOpenError
        As :func:`configure_drive` and :func:`configure_sensor`.

    """
    slaves = [slave for joint in joints for slave in (joint.drive, joint.sensor)]
    for slave in slaves:
        slave.heartbeat_state = None
        slave.booted = False
        link.send_nmt(cd.NMT_RESET_COMMUNICATION, slave.node)
    # Only the boot-up counts: a heartbeat from before the reset does not say it was done.
    link.pump(config.boot_timeout, lambda: all(s.booted for s in slaves))
    silent = [s.label for s in slaves if not s.booted]
    if silent:
        msg = (f'no boot-up within {config.boot_timeout:g} s of the NMT reset '
               f'communication from {", ".join(silent)}: powered, on the bus, at that ID?')
        raise CanOpenTimeoutError(msg)
    sdo = SdoClient(link.exchange, timeout=config.sdo_timeout)
    in_fault = []
    for joint in joints:
        if configure_drive(sdo, config, joint):
            in_fault.append(joint)
        configure_sensor(sdo, config, joint.sensor.node)
    for slave in slaves:
        slave.heartbeat_state = None
        link.send_nmt(cd.NMT_START, slave.node)
    # Wait for a heartbeat sent after the start command, each a producer period apart.
    link.pump(max(config.boot_timeout, 3 * config.heartbeat_period), lambda: all(
        s.heartbeat_state == cd.NMT_OPERATIONAL for s in slaves))
    late = [f'{s.label} ({frames.nmt_name(s.heartbeat_state)})' for s in slaves
            if s.heartbeat_state != cd.NMT_OPERATIONAL]
    if late:
        msg = (f'not operational within {config.boot_timeout:g} s of the NMT start: '
               f'{", ".join(late)}')
        raise CanOpenTimeoutError(msg)
    return in_fault


def configure_common(sdo: SdoClient, config: MasterConfig, node: int, product: int,
                     device_type: int) -> None:
    """Check a slave's identity, device type and SYNC consumer; write its cycle and heartbeats.

    Raises
    ------
    CanOpenError
        For another identity 1018h or device type 1000h than expected, or a COB-ID SYNC 1005h
        other than 80h consumed.

    """
    found = (sdo.read_unsigned(node, cd.IDENTITY, 1), sdo.read_unsigned(node, cd.IDENTITY, 2))
    if found != (cd.VENDOR_ID, product):
        msg = (f'node {node}: identity {object_name(cd.IDENTITY, 1)}/2 is vendor '
               f'0x{found[0]:08X}, product 0x{found[1]:08X}; expected vendor '
               f'0x{cd.VENDOR_ID:08X}, product 0x{product:08X}: wrong device at this ID?')
        raise CanOpenError(msg)
    found_type = sdo.read_unsigned(node, cd.DEVICE_TYPE, 0)
    if found_type != device_type:
        msg = (f'node {node}: device type {object_name(cd.DEVICE_TYPE, 0)} is '
               f'0x{found_type:08X}, expected 0x{device_type:08X}')
        raise CanOpenError(msg)
    sync_cob = sdo.read_unsigned(node, cd.COB_ID_SYNC, 0)
    if sync_cob & cd.COB_ID_MASK != cd.SYNC_COB_ID or sync_cob & cd.SYNC_PRODUCER:
        msg = (f'node {node}: COB-ID SYNC {object_name(cd.COB_ID_SYNC, 0)} is '
               f'0x{sync_cob:08X}, expected 0x{cd.SYNC_COB_ID:X} consumed (bit 30 clear: '
               f'only the master produces SYNC)')
        raise CanOpenError(msg)
    sdo.write_unsigned(node, cd.CYCLE_PERIOD, 0, round(config.period * 1e6), 4)
    consumer = (config.master_id << 16) | round(config.heartbeat_timeout * 1e3)
    sdo.write_unsigned(node, cd.CONSUMER_HEARTBEAT_TIME, 1, consumer, 4)
    sdo.write_unsigned(node, cd.PRODUCER_HEARTBEAT_TIME, 0,
                       round(config.heartbeat_period * 1e3), 2)


def configure_drive(sdo: SdoClient, config: MasterConfig, joint: JointRecord) -> bool:
    """Configure a joint's drive; return whether it is in a fault start-up may reset (8130h).

    A drive in fault has its error code 603Fh noted in ``joint.emcy_code``.

    Raises
    ------
    CanOpenError
        As :func:`configure_common`; for a drive that does not take profile velocity mode; for
        a drive in any other fault, naming its error code.

    """
    node = joint.drive.node
    configure_common(sdo, config, node, cd.DRIVE_PRODUCT_CODE, cd.DRIVE_DEVICE_TYPE)
    units = config.units
    # First what a lost connection does, so that a lost master stops the motor from now on.
    sdo.write_signed(node, cd.ABORT_CONNECTION_OPTION_CODE, 0, ABORT_CONNECTION_OPTION, 2)
    sdo.write_unsigned(node, cd.ERROR_BEHAVIOUR, cd.ERROR_BEHAVIOUR_COMMUNICATION_SUB,
                       ERROR_BEHAVIOUR, 1)
    sdo.write_signed(node, cd.MODES_OF_OPERATION, 0, cd.PROFILE_VELOCITY_MODE, 1)
    sdo.write_signed(node, cd.QUICK_STOP_OPTION_CODE, 0, cd.QUICK_STOP_RAMP_THEN_DISABLE, 2)
    ramp = units.acceleration_to_drive(config.acceleration)
    sdo.write_unsigned(node, cd.PROFILE_ACCELERATION, 0, ramp, 4)
    sdo.write_unsigned(node, cd.PROFILE_DECELERATION, 0, ramp, 4)
    sdo.write_unsigned(node, cd.QUICK_STOP_DECELERATION, 0,
                       units.acceleration_to_drive(config.quick_stop_deceleration), 4)
    mode = sdo.read_signed(node, cd.MODES_OF_OPERATION_DISPLAY, 0)
    if mode != cd.PROFILE_VELOCITY_MODE:
        msg = (f'node {node}: modes of operation display '
               f'{object_name(cd.MODES_OF_OPERATION_DISPLAY, 0)} is {mode} after writing '
               f'{cd.PROFILE_VELOCITY_MODE} (profile velocity)')
        raise CanOpenError(msg)
    for pdo in _DRIVE_PDOS:
        configure_pdo(sdo, node, *pdo)
    state = cia402.decode_state(sdo.read_unsigned(node, cd.STATUSWORD, 0))
    if not cia402.is_fault(state):
        return False
    code = sdo.read_unsigned(node, cd.ERROR_CODE, 0)
    joint.emcy_code = code
    if code not in AUTO_RESET_CODES:
        msg = (f'{joint.drive.label} is in {state} with error code 0x{code:04X} '
               f'{cd.ERROR_CODES.get(code, "(unknown)")} ({object_name(cd.ERROR_CODE, 0)})'
               f': the driver clears only a lost master heartbeat (0x8130) by itself; '
               f'remove the cause and clear the fault, then start again')
        raise CanOpenError(msg)
    return True


def configure_sensor(sdo: SdoClient, config: MasterConfig, node: int) -> None:
    """Configure a sensor board: as :func:`configure_common`, then its two TPDOs."""
    configure_common(sdo, config, node, cd.SENSOR_PRODUCT_CODE, cd.SENSOR_DEVICE_TYPE)
    for pdo in _SENSOR_PDOS:
        configure_pdo(sdo, node, *pdo)


def configure_pdo(sdo: SdoClient, node: int, communication: int, mapping: int, base: int,
                  layout: Iterable[tuple[int, int, int]]) -> None:
    """Check a PDO against can_dictionary; rewrite it per CiA 301 where it differs.

    The COB-ID matches on its 11-bit identifier and bit 31 (valid); bit 30 (no RTR) is the
    device's and kept.
    """
    wanted = [(index << 16) | (sub << 8) | bits for index, sub, bits in layout]
    cob_id = base + node
    found_cob = sdo.read_unsigned(node, communication, 1)
    found_type = sdo.read_unsigned(node, communication, 2)
    count = sdo.read_unsigned(node, mapping, 0)
    entries = [sdo.read_unsigned(node, mapping, sub) for sub in range(1, count + 1)]
    no_rtr = found_cob & cd.PDO_COB_ID_NO_RTR
    if found_cob & ~cd.PDO_COB_ID_NO_RTR == cob_id \
            and found_type == cd.PDO_TRANSMISSION_SYNCHRONOUS and entries == wanted:
        return
    # CiA 301: make the PDO invalid, set the mapping count to 0, write the entries, the
    # count, then the COB-ID with the PDO valid again.
    sdo.write_unsigned(node, communication, 1, cob_id | no_rtr | cd.PDO_COB_ID_INVALID, 4)
    sdo.write_unsigned(node, communication, 2, cd.PDO_TRANSMISSION_SYNCHRONOUS, 1)
    sdo.write_unsigned(node, mapping, 0, 0, 1)
    for sub, entry in enumerate(wanted, start=1):
        sdo.write_unsigned(node, mapping, sub, entry, 4)
    sdo.write_unsigned(node, mapping, 0, len(wanted), 1)
    sdo.write_unsigned(node, communication, 1, cob_id | no_rtr, 4)

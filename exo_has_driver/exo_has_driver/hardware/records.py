"""What the master tracks of each slave and joint: plain records, one thread writing at a time.

The caller's thread writes them during start-up (:mod:`.startup`), then only the I/O thread
(:class:`~exo_has_driver.hardware.master.Master`). ``JointRecord.received`` collects the
``*_TPDO`` bits of a SYNC's TPDOs, until :data:`ALL_TPDOS` completes a sample.
"""

from __future__ import annotations

import math

from exo_has_driver import can_dictionary as cd
from exo_has_driver.hardware import cia402, frames
from exo_has_driver.hardware.config import JointConfig
from exo_has_driver.hardware.units import SensorFault

DRIVE_TPDO = 1
SENSOR_TPDO1 = 2
SENSOR_TPDO2 = 4
ALL_TPDOS = DRIVE_TPDO | SENSOR_TPDO1 | SENSOR_TPDO2


class SlaveRecord:
    """What the master tracks of one slave."""

    __slots__ = (
        'booted',
        'heartbeat_state',
        'heartbeat_time',
        'joint',
        'label',
        'missing',
        'nmt_start_time',
        'node',
        'rebooted',
        'seen',
    )

    def __init__(self, node: int, joint: str, role: str) -> None:
        self.node = node
        self.joint = joint
        self.label = f'{joint} {role} (node {node})'
        self.heartbeat_time: float | None = None
        self.heartbeat_state: int | None = None
        self.seen = True
        self.missing = 0
        self.booted = False  # a boot-up came since the start's reset communication
        self.rebooted = False  # a boot-up came while running: its configuration is lost
        self.nmt_start_time = -math.inf  # when the latch last sent it NMT start


class JointRecord:
    """What the master tracks of one joint: its slaves, its RPDO and its newest TPDO values."""

    __slots__ = (
        'config',
        'counter',
        'current',
        'drive',
        'emcy_code',
        'enabled_syncs',
        'fault',
        'fault_reset',
        'fault_reset_until',
        'last_cw',
        'position',
        'pressure_a',
        'pressure_b',
        'received',
        'rpdo',
        'sensor',
        'stamp',
        'state',
        'status',
        'target',
        'velocity',
        'velocity_sensor',
    )

    def __init__(self, config: JointConfig) -> None:
        self.config = config
        self.drive = SlaveRecord(config.drive_id, config.name, 'drive')
        self.sensor = SlaveRecord(config.sensor_id, config.name, 'sensor board')
        self.rpdo = frames.rpdo1(config.drive_id)
        self.last_cw = cd.CW_DISABLE_VOLTAGE
        self.target = 0
        self.state = cia402.UNKNOWN
        self.fault_reset = False
        self.fault_reset_until = -1.0
        self.emcy_code: int | None = None
        self.enabled_syncs = 0  # SYNCs in a row sent with enable operation
        self.received = 0
        self.stamp = 0.0
        self.velocity = 0
        self.current = 0
        self.position = 0
        self.pressure_a = 0
        self.pressure_b = 0
        self.velocity_sensor = 0
        self.status = 0
        self.counter = 0
        self.fault: SensorFault | None = None

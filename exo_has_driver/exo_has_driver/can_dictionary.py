"""The CAN interface of the HAS hardware: node IDs, objects, PDO layouts, units and timing.

One place for what the driver (the CANopen master) and the simulated devices agree on; the
full description, with the reasons, is ``config/canopen/README.md`` and the EDS files next to
it. ROS-free and free of python-can, so both sides and the tests import it cheaply.

Per joint, two CANopen slaves share the bus with the driver:

* a COPLEY-like servo drive (CiA 402, profile velocity mode) at node ID :data:`DRIVE_NODE_IDS`;
* the HAS sensor board (the STM32 of the paper's section 4.2) at :data:`SENSOR_NODE_IDS`,
  which samples the cylinder's displacement sensor and the two chamber pressure sensors.
"""

from __future__ import annotations

import struct
from typing import Final

#: CANopen node ID of each joint's motor drive.
DRIVE_NODE_IDS: Final = {'left_hip': 1, 'left_knee': 2, 'right_hip': 3, 'right_knee': 4}

#: CANopen node ID of each joint's sensor board.
SENSOR_NODE_IDS: Final = {'left_hip': 17, 'left_knee': 18, 'right_hip': 19, 'right_knee': 20}

#: Node ID of the driver (the master) in its own heartbeat, consumed by every slave.
MASTER_NODE_ID: Final = 127

# --- CiA 301 communication objects (COB-IDs of the pre-defined connection set) -------------
SYNC_COB_ID: Final = 0x080
EMCY_BASE: Final = 0x080  # + node ID
TPDO1_BASE: Final = 0x180  # + node ID
RPDO1_BASE: Final = 0x200  # + node ID
TPDO2_BASE: Final = 0x280  # + node ID
SDO_TX_BASE: Final = 0x580  # + node ID (server to client)
SDO_RX_BASE: Final = 0x600  # + node ID (client to server)
HEARTBEAT_BASE: Final = 0x700  # + node ID

# --- CiA 301 network management (NMT) -------------------------------------------------------
NMT_COB_ID: Final = 0x000  # data: command, node ID (0: every node)
NMT_START: Final = 0x01
NMT_STOP: Final = 0x02
NMT_ENTER_PRE_OPERATIONAL: Final = 0x80
NMT_RESET_NODE: Final = 0x81
NMT_RESET_COMMUNICATION: Final = 0x82
#: NMT states as a heartbeat reports them (its first byte, bit 7 masked); 0 is the boot-up.
NMT_BOOT_UP: Final = 0x00
NMT_STOPPED: Final = 0x04
NMT_OPERATIONAL: Final = 0x05
NMT_PRE_OPERATIONAL: Final = 0x7F

# --- CiA 301 communication profile objects (both devices) ----------------------------------
DEVICE_TYPE: Final = 0x1000  # UNSIGNED32
ERROR_REGISTER: Final = 0x1001  # UNSIGNED8
COB_ID_SYNC: Final = 0x1005  # UNSIGNED32
CYCLE_PERIOD: Final = 0x1006  # UNSIGNED32, microseconds
COB_ID_EMCY: Final = 0x1014  # UNSIGNED32
CONSUMER_HEARTBEAT_TIME: Final = 0x1016  # ARRAY of UNSIGNED32: node ID << 16 | ms, sub 1
PRODUCER_HEARTBEAT_TIME: Final = 0x1017  # UNSIGNED16, ms
IDENTITY: Final = 0x1018  # RECORD: 1 vendor ID, 2 product code, 3 revision, 4 serial
ERROR_BEHAVIOUR: Final = 0x1029  # ARRAY of UNSIGNED8, sub 1: on a communication error
RPDO1_COMMUNICATION: Final = 0x1400  # sub 1 COB-ID (bit 31: PDO not valid), 2 transmission
RPDO1_MAPPING: Final = 0x1600  # sub 0 number of entries, sub 1.. index << 16 | sub << 8 | bits
TPDO1_COMMUNICATION: Final = 0x1800
TPDO2_COMMUNICATION: Final = 0x1801
TPDO1_MAPPING: Final = 0x1A00
TPDO2_MAPPING: Final = 0x1A01
#: Transmission type of every PDO here: synchronous, every SYNC.
PDO_TRANSMISSION_SYNCHRONOUS: Final = 1
#: COB-ID bit 31 of a PDO communication parameter: the PDO is not valid (disabled).
PDO_COB_ID_INVALID: Final = 0x80000000
#: COB-ID bit 30 of a PDO communication parameter: no RTR allowed (the device's to keep).
PDO_COB_ID_NO_RTR: Final = 0x40000000
#: The 11-bit CAN identifier in a COB-ID (bit 29 clear: base frames only).
COB_ID_MASK: Final = 0x7FF
#: COB-ID bit 30 of 1005h: the device produces SYNC (only the master may).
SYNC_PRODUCER: Final = 0x40000000

#: Error behaviour 1029h sub 1 (CiA 301), what a communication error (lost heartbeat, bus-off)
#: does to the NMT state: to pre-operational (the default), no change, or to stopped.
ERROR_BEHAVIOUR_PRE_OPERATIONAL: Final = 0
ERROR_BEHAVIOUR_NO_CHANGE: Final = 1
ERROR_BEHAVIOUR_STOPPED: Final = 2
ERROR_BEHAVIOUR_COMMUNICATION_SUB: Final = 1

#: Identity (1018h) and device type (1000h) of each device.
VENDOR_ID: Final = 0x000000AB
DRIVE_PRODUCT_CODE: Final = 0x00001001
SENSOR_PRODUCT_CODE: Final = 0x00002001
DRIVE_DEVICE_TYPE: Final = 0x00020192  # CiA 402 servo drive
SENSOR_DEVICE_TYPE: Final = 0x00000000  # no profile

# --- Timing -------------------------------------------------------------------------------
#: SYNC period at the paper's 200 Hz control rate [s] (object 1006h holds it in microseconds).
SYNC_PERIOD: Final = 0.005
#: Heartbeat producer time of every node, driver included [s] (object 1017h, in ms).
HEARTBEAT_PERIOD: Final = 0.05
#: Heartbeat consumer time [s] (object 1016h, in ms): three producer periods.
HEARTBEAT_TIMEOUT: Final = 0.15

# --- Drive objects (CiA 402 and COPLEY's manufacturer area) ---------------------------------
CONTROLWORD: Final = 0x6040  # UNSIGNED16
STATUSWORD: Final = 0x6041  # UNSIGNED16
MODES_OF_OPERATION: Final = 0x6060  # INTEGER8
MODES_OF_OPERATION_DISPLAY: Final = 0x6061  # INTEGER8
VELOCITY_ACTUAL: Final = 0x606C  # INTEGER32, drive velocity units
TARGET_VELOCITY: Final = 0x60FF  # INTEGER32, drive velocity units
PROFILE_ACCELERATION: Final = 0x6083  # UNSIGNED32, velocity units per second
PROFILE_DECELERATION: Final = 0x6084  # UNSIGNED32, velocity units per second
QUICK_STOP_DECELERATION: Final = 0x6085  # UNSIGNED32, velocity units per second
QUICK_STOP_OPTION_CODE: Final = 0x605A  # INTEGER16
ABORT_CONNECTION_OPTION_CODE: Final = 0x6007  # INTEGER16
ERROR_CODE: Final = 0x603F  # UNSIGNED16, CiA 301 emergency error code of the last fault
CURRENT_ACTUAL: Final = 0x221C  # INTEGER16, COPLEY's actual motor current, 0.01 A
PROFILE_VELOCITY_MODE: Final = 3
#: Quick stop option code 605Ah the master writes: brake on the quick stop ramp 6085h, then
#: switch on disabled.
QUICK_STOP_RAMP_THEN_DISABLE: Final = 2

#: Abort connection option code 6007h (CiA 402): what the drive does to the motor when the
#: connection to the master is lost (heartbeat consumer timeout, bus-off, NMT leaving
#: operational): nothing, fault (fault reaction), disable voltage (the motor coasts), or quick
#: stop (brake on 6085h, then per 605Ah).
ABORT_CONNECTION_NO_ACTION: Final = 0
ABORT_CONNECTION_FAULT: Final = 1
ABORT_CONNECTION_DISABLE_VOLTAGE: Final = 2
ABORT_CONNECTION_QUICK_STOP: Final = 3

#: Default encoder resolution [counts per motor revolution]: a 1024-line incremental encoder
#: read in quadrature, as on the Maxon-class motors COPLEY drives are paired with.
ENCODER_COUNTS: Final = 4096
#: Default motor revolutions per pump revolution: the paper's pump is coupled directly.
GEAR_RATIO: Final = 1.0
#: Default drive velocity unit [encoder counts/s per unit]: COPLEY's CANopen 0.1 counts/s.
VELOCITY_UNIT: Final = 0.1
#: Default drive current unit [A per unit]: COPLEY's 0.01 A.
CURRENT_UNIT: Final = 0.01

# --- Sensor board objects (manufacturer area, our design) -----------------------------------
SENSOR_VALUES: Final = 0x2100  # RECORD: 1 position, 2 pressure A, 3 pressure B, 4 velocity
SENSOR_POSITION_SUB: Final = 1  # INTEGER32, micrometres from the fully retracted end
SENSOR_PRESSURE_A_SUB: Final = 2  # INTEGER16, kPa gauge, rodless chamber
SENSOR_PRESSURE_B_SUB: Final = 3  # INTEGER16, kPa gauge, rod chamber
SENSOR_VELOCITY_SUB: Final = 4  # INTEGER32, micrometres per second
SENSOR_STATUS: Final = 0x2101  # UNSIGNED16, the SENSOR_FAULT_* bits
SENSOR_COUNTER: Final = 0x2102  # UNSIGNED16, sample counter, +1 per SYNC, wraps

POSITION_UNIT: Final = 1e-6  # m per unit
PRESSURE_UNIT: Final = 1e3  # Pa per unit
VELOCITY_SENSOR_UNIT: Final = 1e-6  # m/s per unit

#: Raw values a sensor channel sends when it has no valid reading (open wire, ADC fault).
NO_READING_I32: Final = -0x80000000
NO_READING_I16: Final = -0x8000

#: Valid range of the sensors: a position more than this beyond either stroke end [m], or a
#: gauge pressure outside [SENSOR_PRESSURE_MIN, SENSOR_PRESSURE_MAX] [Pa], is a sensor fault.
SENSOR_POSITION_TOLERANCE: Final = 1e-3
SENSOR_PRESSURE_MIN: Final = -0.1e6
SENSOR_PRESSURE_MAX: Final = 30e6

SENSOR_FAULT_POSITION: Final = 0x0001
SENSOR_FAULT_PRESSURE_A: Final = 0x0002
SENSOR_FAULT_PRESSURE_B: Final = 0x0004
SENSOR_FAULT_VELOCITY: Final = 0x0008

# --- PDO layouts (little endian, as CANopen) -----------------------------------------------
#: Drive RPDO1 (driver to drive, applied at the next SYNC): controlword, target velocity.
DRIVE_RPDO1: Final = struct.Struct('<Hi')
#: Drive TPDO1 (sent after every SYNC): statusword, velocity actual, current actual.
DRIVE_TPDO1: Final = struct.Struct('<Hih')
#: Sensor TPDO1 (after every SYNC): position [um], pressure A [kPa], pressure B [kPa].
SENSOR_TPDO1: Final = struct.Struct('<ihh')
#: Sensor TPDO2 (after every SYNC): velocity [um/s], status bits, sample counter.
SENSOR_TPDO2: Final = struct.Struct('<iHH')

#: (index, subindex, size in bits) of each mapped object, in order, as 1600h/1A00h/1A01h hold.
DRIVE_RPDO1_MAP: Final = ((CONTROLWORD, 0, 16), (TARGET_VELOCITY, 0, 32))
DRIVE_TPDO1_MAP: Final = ((STATUSWORD, 0, 16), (VELOCITY_ACTUAL, 0, 32),
                          (CURRENT_ACTUAL, 0, 16))
SENSOR_TPDO1_MAP: Final = ((SENSOR_VALUES, SENSOR_POSITION_SUB, 32),
                           (SENSOR_VALUES, SENSOR_PRESSURE_A_SUB, 16),
                           (SENSOR_VALUES, SENSOR_PRESSURE_B_SUB, 16))
SENSOR_TPDO2_MAP: Final = ((SENSOR_VALUES, SENSOR_VELOCITY_SUB, 32), (SENSOR_STATUS, 0, 16),
                           (SENSOR_COUNTER, 0, 16))

# --- CiA 402 controlword commands and statusword states -------------------------------------
CW_SHUTDOWN: Final = 0x0006
CW_SWITCH_ON: Final = 0x0007
CW_ENABLE_OPERATION: Final = 0x000F
CW_DISABLE_VOLTAGE: Final = 0x0000
CW_QUICK_STOP: Final = 0x0002
CW_DISABLE_OPERATION: Final = 0x0007
CW_FAULT_RESET: Final = 0x0080  # on its rising edge

#: (mask, value) of the statusword for each CiA 402 state.
STATES: Final = {
    'not ready to switch on': (0x004F, 0x0000),
    'switch on disabled': (0x004F, 0x0040),
    'ready to switch on': (0x006F, 0x0021),
    'switched on': (0x006F, 0x0023),
    'operation enabled': (0x006F, 0x0027),
    'quick stop active': (0x006F, 0x0007),
    'fault reaction active': (0x004F, 0x000F),
    'fault': (0x004F, 0x0008),
}

#: EMCY code of a lost heartbeat (CiA 301 "life guard error or heartbeat error").
ERROR_HEARTBEAT_LOST: Final = 0x8130
#: EMCY code of another communication error (CiA 301 "communication, generic"): here, a drive
#: sent out of NMT operational.
ERROR_COMMUNICATION: Final = 0x8100

#: CiA 301 emergency error codes the simulated drive raises and the driver names.
ERROR_CODES: Final = {
    0x0000: 'no error',
    0x2310: 'continuous over-current',
    0x3210: 'DC link over-voltage',
    0x4310: 'drive over-temperature',
    0x7300: 'sensor (motor encoder) fault',
    0x8100: 'communication error (left NMT operational)',
    0x8130: 'heartbeat of the master lost',
    0x8611: 'following error',
}


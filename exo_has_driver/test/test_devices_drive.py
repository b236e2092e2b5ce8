"""The simulated CiA 402 drive: state machine, profile ramps, quick stop, faults, units."""

from __future__ import annotations

import itertools
import math
import struct

import canopen
import pytest
from devices_bench import Bench, BenchMaster, FakeClock

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.drive import motor_current, ramp
from exo_has_driver.hardware.cia402 import decode_state
from exo_has_sim.plant import PlantSample

DRIVE_TPDO, BOARD_TPDO1, BOARD_TPDO2 = 0x181, 0x191, 0x291


def command(master: BenchMaster, clock: FakeClock, controlword: int,
            target: int = 0) -> tuple[str, int, int]:
    """Send RPDO1 and a SYNC; return the state, velocity actual and current of the TPDO."""
    master.send(cd.RPDO1_BASE + 1, cd.DRIVE_RPDO1.pack(controlword, target))
    (tpdo,) = master.sync(clock, expect=(DRIVE_TPDO,))
    statusword, velocity, current = cd.DRIVE_TPDO1.unpack(tpdo)
    return decode_state(statusword), velocity, current


def enable(master: BenchMaster, clock: FakeClock) -> None:
    master.nmt(0x01)
    states = [command(master, clock, cw)[0] for cw in (0x06, 0x07, 0x0F)]
    assert states == ['ready to switch on', 'switched on', 'operation enabled']


def test_ramp_accelerates_and_decelerates_through_zero_at_their_own_rates() -> None:
    assert ramp(0.0, 100.0, 10.0, 20.0, 5.0) == pytest.approx(50.0, abs=1e-12)
    assert ramp(0.0, 100.0, 10.0, 20.0, 50.0) == 100.0
    # 100 to 0 at 20/s takes 5 s, then 1 s at 10/s towards -100.
    assert ramp(100.0, -100.0, 10.0, 20.0, 6.0) == pytest.approx(-10.0, abs=1e-12)
    assert ramp(-80.0, -30.0, 10.0, 20.0, 1.0) == pytest.approx(-60.0, abs=1e-12)
    assert ramp(-30.0, -30.0, 10.0, 20.0, 1.0) == -30.0


def test_motor_current_divides_the_pump_torque_by_the_efficiency_when_motoring() -> None:
    def sample(speed: float) -> PlantSample:
        return PlantSample(position=0.05, velocity=0.0, pressure_a=10e6, pressure_b=0.0,
                           motor_speed=speed, motor_speed_command=speed, load_force=300.0,
                           valve_mode=1)
    displacement = 0.4e-6 / (2.0 * math.pi)  # m^3/rad, the paper's 0.4 mL/r
    # 0.6366 N m of pump torque, 0.85 efficiency, 0.1 N m/A
    assert motor_current(sample(50.0), displacement, 0.85, 1.0, 0.1) == pytest.approx(
        7.490, abs=1e-3)
    assert motor_current(sample(-50.0), displacement, 0.85, 1.0, 0.1) == pytest.approx(
        5.411, abs=1e-3)
    assert motor_current(sample(50.0), displacement, 0.85, 2.0, 0.1) == pytest.approx(
        3.745, abs=1e-3)


def test_the_enable_sequence_must_pass_every_state_and_disable_voltage_drops_it(
        bench: Bench) -> None:
    rig, master, clock = bench
    master.nmt(0x01)
    assert command(master, clock, 0x0F)[0] == 'switch on disabled'  # no shortcut
    assert command(master, clock, 0x07)[0] == 'switch on disabled'
    assert command(master, clock, 0x06)[0] == 'ready to switch on'
    assert command(master, clock, 0x0F)[0] == 'operation enabled'  # switch on + enable
    assert command(master, clock, 0x07)[0] == 'switched on'  # disable operation
    assert command(master, clock, 0x0F)[0] == 'operation enabled'
    assert command(master, clock, 0x00)[0] == 'switch on disabled'
    assert rig.joints['left_hip'].plant.sample().motor_speed_command == 0.0


def test_a_target_velocity_turns_the_motor_within_the_ramp_time_and_extends_the_cylinder(
        bench: Bench) -> None:
    rig, master, clock = bench
    drive = rig.joints['left_hip'].drive
    master.node(1).sdo[cd.PROFILE_ACCELERATION].raw = 10_000_000
    acceleration = 10_000_000 * drive.rad_s_per_unit  # 1534 rad/s^2
    target_speed = 100.0  # rad/s of the pump
    target = round(target_speed / drive.rad_s_per_unit)  # 651 899 units of 0.1 counts/s
    ramp_time = target / 10_000_000  # 65.2 ms
    assert ramp_time == pytest.approx(0.0652, abs=1e-4)
    enable(master, clock)
    command(master, clock, 0x0F, target)  # applied at this SYNC: the ramp starts here
    board = rig.joints['left_hip'].board
    start = cd.SENSOR_TPDO1.unpack(master.sync(clock, 0.0, expect=(BOARD_TPDO1,))[0])[0]
    speeds, reached = [], []
    for k in range(1, 31):
        _, velocity, current = command(master, clock, 0x0F, target)
        speed = velocity * drive.rad_s_per_unit
        speeds.append(speed)
        reached.append(bool(drive.get(cd.STATUSWORD) & 0x0400))
        assert speed <= acceleration * k * cd.SYNC_PERIOD + 1e-6  # ramp-limited
    assert 50.0 < speeds[9] < 77.0  # 50 ms into the 65 ms ramp: a * t = 76.7 rad/s
    assert not any(reached[:13])  # not before the ramp time
    # 150 ms: the ramp time plus 17 motor time constants of 5 ms.
    assert speeds[-1] == pytest.approx(target_speed, abs=0.5)
    assert reached[-1]
    assert 0 < current < 2000  # 0.01 A units: under 20 A
    position, _, _ = cd.SENSOR_TPDO1.unpack(master.wait_for(BOARD_TPDO1, 33)[-1])
    velocity_um, status, _ = cd.SENSOR_TPDO2.unpack(master.wait_for(BOARD_TPDO2, 33)[-1])
    params = board.plant.params
    area = math.pi / 4.0 * params.bore_diameter ** 2
    # The pump's flow less its leakage at the load's pressure, over the rodless area: 46 mm/s
    # (within 0.2 %: the model holds the pressure of a load that accelerates a little still).
    pressure = board.plant.sample().pressure_a
    net_speed = (params.pump_displacement * target_speed - params.pump_leakage * pressure) / area
    assert 0.9 * net_speed < velocity_um * 1e-6 < 1.25 * net_speed
    assert velocity_um == pytest.approx(board.plant.sample().velocity * 1e6, abs=0.5)
    assert position - start > 2_000  # um: extending
    assert status == 0


def test_quick_stop_brakes_on_its_ramp_then_ends_in_switch_on_disabled(bench: Bench) -> None:
    rig, master, clock = bench
    drive = rig.joints['left_hip'].drive
    master.node(1).sdo[cd.QUICK_STOP_DECELERATION].raw = 20_000_000  # 3068 rad/s^2
    target = round(100.0 / drive.rad_s_per_unit)
    enable(master, clock)
    for _ in range(10):
        command(master, clock, 0x0F, target)  # 100 rad/s within 7 ms at the default ramp
    stop_time = target / 20_000_000  # 32.6 ms
    states, speeds = [], []
    for _ in range(14):
        state, velocity, _ = command(master, clock, 0x02, target)
        states.append(state)
        speeds.append(velocity * drive.rad_s_per_unit)
    steps = math.ceil(stop_time / cd.SYNC_PERIOD)  # the 7th SYNC after the quick stop
    assert states[:steps] == ['quick stop active'] * steps
    assert states[steps:] == ['switch on disabled'] * (14 - steps)
    deceleration = 20_000_000 * drive.rad_s_per_unit
    for k in range(steps):  # braked on the ramp, not faster (the motor lags it by 5 ms)
        assert speeds[k] >= 100.0 - deceleration * k * cd.SYNC_PERIOD - 0.5
    assert all(later < earlier for earlier, later in itertools.pairwise(speeds[1:steps]))
    assert speeds[steps - 1] < 40.0
    assert abs(speeds[-1]) < 1.0
    assert drive.plant.sample().motor_speed_command == 0.0


def test_an_injected_fault_sends_emcy_and_only_a_fault_reset_leaves_it(bench: Bench) -> None:
    rig, master, clock = bench
    enable(master, clock)
    command(master, clock, 0x0F, 300_000)
    rig.drive_fault('left_hip', 0x2310)
    emcy = master.wait_for(cd.EMCY_BASE + 1)[0]
    assert emcy == struct.pack('<HB5x', 0x2310, 0x03)  # generic + current error register
    node = master.node(1)
    assert node.sdo[cd.ERROR_CODE].raw == 0x2310
    assert node.sdo[0x1001].raw == 0x03
    assert decode_state(node.sdo[cd.STATUSWORD].raw) == 'fault'
    assert rig.joints['left_hip'].plant.sample().motor_speed_command == 0.0
    for controlword in (0x06, 0x07, 0x0F, 0x00, 0x02):
        assert command(master, clock, controlword)[0] == 'fault'
    assert command(master, clock, 0x80)[0] == 'switch on disabled'
    assert master.wait_for(cd.EMCY_BASE + 1, 2)[1] == bytes(8)  # error reset
    assert node.sdo[cd.ERROR_CODE].raw == 0x2310  # the last fault's code stays
    assert node.sdo[0x1001].raw == 0
    enable(master, clock)


def test_losing_the_master_heartbeat_faults_the_drive_with_8130_and_leaves_operational(
        bench: Bench) -> None:
    rig, master, clock = bench
    enable(master, clock)
    master.heartbeat()  # arms the consumer (150 ms)
    command(master, clock, 0x0F, 300_000)
    assert not [c for c, _ in master.frames if c == cd.EMCY_BASE + 1]
    clock.now += 0.2  # no heartbeat for 200 ms: the timer thread notices
    emcy = master.wait_for(cd.EMCY_BASE + 1)[0]
    assert struct.unpack('<HB5x', emcy) == (0x8130, 0x11)
    # The EDS defaults: 6007h = 1 (fault), 1029h sub 1 = 0 (to pre-operational: no PDOs).
    node = master.node(1)
    assert node.sdo[cd.ERROR_CODE].raw == 0x8130
    assert decode_state(node.sdo[cd.STATUSWORD].raw) == 'fault'
    assert rig.joint('left_hip').drive.nmt_state == cd.NMT_PRE_OPERATIONAL
    assert rig.joint('left_hip').plant.sample().motor_speed_command == 0.0
    # The sensor board reports the loss too, and keeps its TPDOs flowing.
    assert struct.unpack('<HB5x', master.wait_for(cd.EMCY_BASE + 17)[0]) == (0x8130, 0x11)
    count = len(master.wait_for(BOARD_TPDO1))
    master.sync(clock, expect=(BOARD_TPDO1,))
    assert len(master.wait_for(BOARD_TPDO1)) == count + 1


def test_with_6007h_quick_stop_and_1029h_no_change_a_lost_master_brakes_the_motor(
        bench: Bench) -> None:
    rig, master, clock = bench
    node = master.node(1)
    node.sdo[cd.ABORT_CONNECTION_OPTION_CODE].raw = cd.ABORT_CONNECTION_QUICK_STOP
    node.sdo[cd.ERROR_BEHAVIOUR][1].raw = cd.ERROR_BEHAVIOUR_NO_CHANGE
    enable(master, clock)
    for _ in range(20):
        master.heartbeat()
        command(master, clock, 0x0F, 300_000)
    drive = rig.joint('left_hip').drive
    assert drive.to_rad_s(drive.setpoint) > 40.0
    clock.now += 0.2
    emcy = master.wait_for(cd.EMCY_BASE + 1)[0]
    assert struct.unpack('<HB5x', emcy) == (0x8130, 0x11)
    # Still operational: the TPDOs flow, and enable operation does not leave the quick stop.
    assert command(master, clock, 0x0F, 300_000)[0] in ('quick stop active',
                                                         'switch on disabled')
    for _ in range(10):
        state = command(master, clock, 0x0F, 300_000)[0]
    assert state == 'switch on disabled'
    assert drive.nmt_state == cd.NMT_OPERATIONAL
    assert rig.joint('left_hip').plant.sample().motor_speed_command == 0.0
    assert node.sdo[cd.ERROR_CODE].raw == 0  # not a fault
    master.heartbeat()  # back: error reset
    assert master.wait_for(cd.EMCY_BASE + 1, 2)[1] == bytes(8)


@pytest.mark.parametrize(('option', 'expected'), [
    (cd.ABORT_CONNECTION_QUICK_STOP, 'quick stop active'),
    (cd.ABORT_CONNECTION_DISABLE_VOLTAGE, 'switch on disabled'),
    (cd.ABORT_CONNECTION_FAULT, 'fault'),
    (cd.ABORT_CONNECTION_NO_ACTION, 'operation enabled'),
])
def test_an_nmt_command_out_of_operational_acts_per_6007h(bench: Bench, option: int,
                                                          expected: str) -> None:
    rig, master, clock = bench
    node = master.node(1)
    node.sdo[cd.ABORT_CONNECTION_OPTION_CODE].raw = option
    enable(master, clock)
    for _ in range(10):
        command(master, clock, 0x0F, 300_000)
    master.nmt(cd.NMT_ENTER_PRE_OPERATIONAL, 1)
    drive = rig.joint('left_hip').drive
    assert decode_state(node.sdo[cd.STATUSWORD].raw) == expected
    assert drive.nmt_state == cd.NMT_PRE_OPERATIONAL
    if option == cd.ABORT_CONNECTION_FAULT:
        assert node.sdo[cd.ERROR_CODE].raw == cd.ERROR_COMMUNICATION


def test_6007h_and_1029h_refuse_values_they_do_not_define(bench: Bench) -> None:
    _, master, _ = bench
    node = master.node(1)
    with pytest.raises(canopen.SdoAbortedError, match='0x06090030'):
        node.sdo[cd.ABORT_CONNECTION_OPTION_CODE].raw = 4
    with pytest.raises(canopen.SdoAbortedError, match='0x06090030'):
        node.sdo[cd.ERROR_BEHAVIOUR][1].raw = 3


def test_modes_other_than_profile_velocity_and_other_quick_stop_options_are_refused(
        bench: Bench) -> None:
    _, master, _ = bench
    sdo = master.node(1).sdo
    for index, value in ((cd.MODES_OF_OPERATION, 1), (cd.MODES_OF_OPERATION, 8),
                         (cd.QUICK_STOP_OPTION_CODE, 6), (cd.PROFILE_ACCELERATION, 0)):
        with pytest.raises(canopen.SdoAbortedError) as aborted:
            sdo[index].raw = value
        assert aborted.value.code == 0x06090030
    sdo[cd.MODES_OF_OPERATION].raw = cd.PROFILE_VELOCITY_MODE
    assert sdo[cd.MODES_OF_OPERATION_DISPLAY].raw == cd.PROFILE_VELOCITY_MODE

"""The CANopen master against the simulated devices (exo_has_driver.devices) on a virtual bus."""

import itertools
import math
import time
import uuid

import can
import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.rig import Rig
from exo_has_driver.errors import (
    CanBusError,
    CanOpenError,
    CanOpenTimeoutError,
    HardwareConfigError,
)
from exo_has_driver.events import CLEAR_TIME, Phase, SafetyKind, Severity
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.config import JointConfig, MasterConfig, infer_valve_mode
from exo_has_driver.hardware.master import Master
from exo_has_sim.parameters import load_parameters
from exo_has_sim.valve import ValveMode

JOINTS = ('left_hip', 'left_knee', 'right_hip', 'right_knee')
PARAMS = {kind: load_parameters(kind) for kind in ('hip', 'knee')}
# Generous waits: the rig's plants and the master share this process and two busy cores.
WAIT = 3.0


def joint_config(name, **ids):
    return JointConfig.from_parameters(name, PARAMS[name.rsplit('_', 1)[1]], **ids)


def config(joints=JOINTS, **settings):
    return MasterConfig(tuple(joint_config(name) for name in joints), **settings)


class FlakyBus(can.BusABC):
    """A virtual bus whose state and sends a test can break."""

    def __init__(self, channel):
        self._inner = can.Bus(interface='virtual', channel=channel)
        self.fake_state = can.BusState.ACTIVE
        self.fail_sends = False
        self.fail_receives = 0  # receives that raise, as on a bad datagram; -1: every one
        super().__init__(channel=channel)

    @property
    def state(self):
        """The state the test set."""
        return self.fake_state

    def send(self, msg, timeout=None):
        """Send, or fail as a full transmit buffer does."""
        if self.fail_sends:
            raise can.CanOperationError('transmit buffer full (test)')
        self._inner.send(msg, timeout)

    def _recv_internal(self, timeout):
        if self.fail_receives:
            self.fail_receives -= self.fail_receives > 0
            raise can.CanOperationError('could not unpack received message (test)')
        return self._inner.recv(timeout), False

    def shutdown(self):
        """Close the inner bus."""
        self._inner.shutdown()
        super().shutdown()


class Setup:
    """A rig of simulated devices and a started master on one virtual bus."""

    def __init__(self, joints=JOINTS, master_bus=None, **settings):
        channel = self.channel = f'test-{uuid.uuid4().hex}'
        self.rig_bus = can.Bus(interface='virtual', channel=channel)
        self.bus = master_bus(channel) if master_bus else can.Bus(interface='virtual',
                                                                  channel=channel)
        self.rig = Rig(self.rig_bus, joints)
        self.rig.start()
        self.master = Master(self.bus, config(joints, **settings))
        self.events = []
        self.samples = []

    def close(self):
        """Stop the master and the rig, close both buses."""
        self.master.close()
        self.rig.stop()
        self.bus.shutdown()
        self.rig_bus.shutdown()

    def pump(self):
        """Collect the master's events and samples."""
        self.events += self.master.take_events()
        self.samples += self.master.take_samples()

    def run(self, seconds, until=None, commands=None):
        """Feed commands every 5 ms for ``seconds`` or until ``until()``; return until()."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            for joint, (speed, enable) in (commands or {}).items():
                self.master.set_command(joint, speed, enable)
            self.pump()
            if until is not None and until():
                return True
            time.sleep(0.005)
        self.pump()
        return until() if until is not None else None

    def event_of(self, kind, severity=Severity.FATAL):
        """Return the first event of a kind and severity so far, or None."""
        return next((e for e in self.events if e.kind == kind and e.severity == severity),
                    None)

    def wait_event(self, kind, severity=Severity.FATAL, commands=None):
        """Run until an event of a kind and severity came; return it."""
        assert self.run(WAIT, lambda: self.event_of(kind, severity) is not None, commands), \
            f'no event of kind {kind}; got {[e.text for e in self.events]}'
        return self.event_of(kind, severity)

    def rig_states(self):
        """Return the CiA 402 state of each simulated drive."""
        return {name: joint.drive.state for name, joint in self.rig.joints.items()}

    def motors_stopped(self):
        """Tell whether every simulated motor stands still."""
        return all(abs(joint.plant.sample().motor_speed) < 0.5
                   for joint in self.rig.joints.values())


@pytest.fixture
def setup():
    made = Setup()
    made.master.start()
    yield made
    made.close()


def test_start_enables_every_drive_and_writes_the_specified_configuration(setup):
    assert setup.master.drive_states() == dict.fromkeys(JOINTS, cia402.OPERATION_ENABLED)
    assert setup.rig_states() == dict.fromkeys(JOINTS, 'operation enabled')
    units = setup.master.config.units
    for joint in setup.rig.joints.values():
        for slave in (joint.drive, joint.board):
            assert slave.get(cd.CONSUMER_HEARTBEAT_TIME, 1) == (127 << 16) | 150
            assert slave.get(cd.PRODUCER_HEARTBEAT_TIME) == 50
            assert slave.get(cd.CYCLE_PERIOD) == 5000
        # 15000 rad/s^2 * 4096 counts / 2 pi / 0.1 counts/s = 97 784 797 units/s.
        assert joint.drive.get(cd.PROFILE_ACCELERATION) == pytest.approx(97_784_797, abs=1)
        assert joint.drive.get(cd.PROFILE_ACCELERATION) == units.acceleration_to_drive(15000.0)
        assert joint.drive.get(cd.QUICK_STOP_DECELERATION) == pytest.approx(195_569_594, abs=1)
        assert joint.drive.get(cd.MODES_OF_OPERATION) == cd.PROFILE_VELOCITY_MODE
        assert joint.drive.get(cd.ABORT_CONNECTION_OPTION_CODE) == \
            cd.ABORT_CONNECTION_QUICK_STOP
        assert joint.drive.get(cd.ERROR_BEHAVIOUR, 1) == cd.ERROR_BEHAVIOUR_NO_CHANGE
        # The TPDO's COB-ID matched on its identifier: its no-RTR bit 30 was left alone.
        assert joint.drive.get(cd.TPDO1_COMMUNICATION, 1) == \
            cd.PDO_COB_ID_NO_RTR | (cd.TPDO1_BASE + joint.drive.node_id)
    setup.run(0.2)
    assert setup.events == []
    assert not setup.master.latched


def test_a_command_turns_the_motor_and_each_state_reports_it(setup):
    # Both retract from standing, where the knee is 3 mm from its extended end: 17 and 23 mm/s
    # for 0.8 s stay well inside the 40 mm stroke.
    commands = dict.fromkeys(JOINTS, (-30.0, True))
    commands['left_knee'] = (-40.0, True)
    setup.run(0.5, commands=commands)
    setup.samples.clear()
    setup.run(0.3, commands=commands)
    assert setup.events == []
    quantum = 1.0 / setup.master.config.units.velocity_per_rad_s  # 1.5e-4 rad/s
    for joint in JOINTS:
        samples = [s for s in setup.samples if s.joint == joint]
        # 0.3 s at 200 Hz is 60 SYNCs; the shared machine may drop a few.
        assert len(samples) >= 30, len(samples)
        last = samples[-1]
        speed = commands[joint][0]
        assert last.motor_speed_command == pytest.approx(speed, abs=quantum)
        assert last.motor_speed == pytest.approx(speed, abs=1.0)
        assert last.drive_state == cia402.OPERATION_ENABLED
        assert last.valve_mode == ValveMode.ASSIST
        assert not last.sensor_fault
        plant = setup.rig.joint(joint).plant.sample()
        # The rig's plant moved on since the sample by at most a few SYNCs at ~0.02 m/s.
        assert last.position == pytest.approx(plant.position, abs=1e-3)
        assert last.pressure_a == pytest.approx(plant.pressure_a, rel=0.05, abs=0.2e6)
        assert all(b.stamp > a.stamp for a, b in itertools.pairwise(samples))
        steps = [(b.counter - a.counter) % 65536 for a, b in itertools.pairwise(samples)]
        assert steps.count(1) >= 0.8 * len(steps), steps
    hip = [s for s in setup.samples if s.joint == 'left_hip']
    # Pumping out of the rodless chamber: the hip retracts.
    assert hip[-1].position < hip[0].position - 1e-4
    assert hip[-1].velocity < 0.0


def test_a_disable_command_switches_the_drive_off_and_the_valve_to_free(setup):
    commands = dict.fromkeys(JOINTS, (30.0, True))
    commands['right_hip'] = (30.0, False)
    assert setup.run(WAIT, lambda: setup.rig_states()['right_hip'] == 'switched on', commands)
    setup.run(0.2, commands=commands)
    last = [s for s in setup.samples if s.joint == 'right_hip'][-1]
    assert last.drive_state == cia402.SWITCHED_ON
    assert last.motor_speed_command == 0.0
    assert abs(last.motor_speed) < 0.5
    assert last.valve_mode == ValveMode.FREE
    assert setup.rig_states()['left_hip'] == 'operation enabled'
    assert setup.events == []


def test_without_fresh_commands_the_drives_are_held_at_zero_speed(setup):
    setup.run(0.3, commands={'left_hip': (80.0, True)})
    assert any(s.motor_speed_command == pytest.approx(80.0, abs=1e-3)
               for s in setup.samples if s.joint == 'left_hip')
    setup.run(0.5)  # no commands: older than the 0.25 s command timeout
    last = [s for s in setup.samples if s.joint == 'left_hip'][-1]
    assert last.motor_speed_command == 0.0
    assert abs(last.motor_speed) < 0.5
    assert last.drive_state == cia402.OPERATION_ENABLED
    assert setup.events == []


def test_an_e_stop_quick_stops_every_drive_latches_and_a_reset_enables_them_again(setup):
    commands = dict.fromkeys(JOINTS, (150.0, True))
    setup.run(0.3, commands=commands)
    assert setup.rig.joint('left_hip').plant.sample().motor_speed == pytest.approx(150.0,
                                                                                   abs=2.0)
    setup.master.request_stop('watchdog: tracking error')
    event = setup.wait_event(SafetyKind.E_STOP, commands=commands)
    assert (event.joint, event.latched) == ('', True)
    assert 'watchdog: tracking error' in event.text
    assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
        JOINTS, 'switch on disabled'), commands)
    # Commands are ignored while latched: the motors stay stopped.
    setup.run(0.2, commands=commands)
    assert setup.motors_stopped()
    assert setup.master.latched
    assert all(s.motor_speed_command == 0.0 for s in setup.samples[-8:])
    setup.events.clear()
    setup.master.request_reset()
    event = setup.wait_event(SafetyKind.RESET, Severity.INFO)
    assert not event.latched
    assert 'latched by emergency stop: watchdog: tracking error' in event.text
    assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
        JOINTS, 'operation enabled'), commands)
    setup.run(0.3, commands=commands)
    assert setup.rig.joint('right_knee').plant.sample().motor_speed == pytest.approx(150.0,
                                                                                     abs=2.0)


def test_a_reset_without_a_latched_stop_says_so(setup):
    setup.master.request_reset()
    event = setup.wait_event(SafetyKind.RESET, Severity.INFO)
    assert event.text == 'reset: no stop was latched'


def inject_drive_fault(rig):
    rig.drive_fault('left_knee', 0x4310, holds=True)  # a hot drive: resets fail until clear


def inject_lost_heartbeat(rig):
    rig.set_heartbeat('right_hip', False, 'sensor')


def inject_sensor_nan(rig):
    rig.set_sensor('left_hip', 'pressure_a', math.nan)


def inject_sensor_out_of_range(rig):
    rig.set_sensor('right_knee', 'position', PARAMS['knee'].stroke + 5e-3)


def inject_silent_bus(rig):
    rig.set_silent('all')


FAULTS = {
    # name: (injection, kind, joint, value, limit, reset refused while it holds)
    'drive fault': (inject_drive_fault, SafetyKind.DRIVE_FAULT, 'left_knee', 0x4310, math.nan,
                    True),
    'lost heartbeat': (inject_lost_heartbeat, SafetyKind.HEARTBEAT_LOST, 'right_hip', None,
                       0.15, True),
    'sensor NaN': (inject_sensor_nan, SafetyKind.SENSOR_FAULT, 'left_hip', math.nan,
                   math.nan, True),
    'sensor out of range': (inject_sensor_out_of_range, SafetyKind.SENSOR_FAULT, 'right_knee',
                            PARAMS['knee'].stroke + 5e-3, PARAMS['knee'].stroke + 1e-3, True),
    'silent bus': (inject_silent_bus, SafetyKind.BUS_OFF, None, math.nan, math.nan, True),
}


@pytest.mark.parametrize('name', list(FAULTS))
def test_each_fault_stops_every_motor_latches_and_a_reset_after_it_clears_releases(setup, name):
    inject, kind, joint, value, limit, refused = FAULTS[name]
    commands = dict.fromkeys(JOINTS, (100.0, True))
    setup.run(0.3, commands=commands)
    assert not setup.motors_stopped()
    inject(setup.rig)
    event = setup.wait_event(kind, commands=commands)
    assert event.latched
    if joint is not None:
        assert event.joint == joint
    if value is None:  # the heartbeat's age
        assert event.value > limit
    else:
        assert event.value == pytest.approx(value, abs=1e-9, nan_ok=True)
    assert event.limit == pytest.approx(limit, abs=1e-9, nan_ok=True)
    assert setup.master.cause is not None
    # Every motor stops, on every joint, and stays stopped despite the commands.
    assert setup.run(WAIT, setup.motors_stopped, commands)
    if name != 'silent bus':  # a cut cable hides the drives' states
        assert setup.run(WAIT, lambda: all(
            state in ('switch on disabled', 'fault') for state in setup.rig_states().values()),
            commands)
    setup.run(0.2, commands=commands)
    assert setup.motors_stopped()
    assert setup.master.latched
    if refused:
        count = len(setup.events)
        setup.master.request_reset()
        assert setup.run(WAIT, lambda: any(
            e.severity == Severity.WARN for e in setup.events[count:]), commands)
        warning = next(e for e in setup.events[count:] if e.severity == Severity.WARN)
        assert warning.latched and warning.text.startswith('reset refused: ')
        assert setup.master.latched
        assert not any(e.kind == SafetyKind.RESET for e in setup.events[count:])
        # Nothing moved meanwhile: no drive was enabled again.
        assert setup.run(0.3, lambda: any(state == 'operation enabled'
                                          for state in setup.rig_states().values()),
                         commands) is False
        assert setup.motors_stopped()
    setup.rig.clear()
    setup.run(0.4, commands=commands)  # heartbeats and TPDOs flow again
    count = len(setup.events)
    setup.master.request_reset()
    assert setup.run(WAIT, lambda: any(
        e.kind == SafetyKind.RESET for e in setup.events[count:]), commands), \
        [e.text for e in setup.events[count:]]
    reset = next(e for e in setup.events[count:] if e.kind == SafetyKind.RESET)
    assert (reset.severity, reset.latched) == (Severity.INFO, False)
    assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
        JOINTS, 'operation enabled'), commands), setup.rig_states()
    setup.run(0.3, commands=commands)
    assert not setup.master.latched, [e.text for e in setup.events[count:]]
    speeds = [j.plant.sample().motor_speed for j in setup.rig.joints.values()]
    assert speeds == pytest.approx([100.0] * 4, abs=2.0)


@pytest.mark.parametrize('breakage', ['error passive', 'failed sends'])
def test_a_bus_fault_stops_and_latches_until_the_bus_recovers(breakage):
    setup = Setup(master_bus=FlakyBus)
    try:
        setup.master.start()
        commands = dict.fromkeys(JOINTS, (100.0, True))
        setup.run(0.3, commands=commands)
        bus = setup.master.bus
        if breakage == 'error passive':
            bus.fake_state = can.BusState.PASSIVE
        else:
            bus.fail_sends = True
        event = setup.wait_event(SafetyKind.BUS_OFF, commands=commands)
        assert event.latched
        expected = 'error passive' if breakage == 'error passive' else 'failed'
        assert expected in event.text
        if breakage == 'error passive':
            # The frames still flow: the drives are stopped.
            assert setup.run(WAIT, setup.motors_stopped, commands)
        count = len(setup.events)
        setup.master.request_reset()
        assert setup.run(WAIT, lambda: any(
            e.severity == Severity.WARN for e in setup.events[count:]), commands)
        bus.fake_state = can.BusState.ACTIVE
        bus.fail_sends = False
        setup.run(0.4, commands=commands)
        count = len(setup.events)
        # A reset may still be refused while the recovery shows (a clean CI run once saw no
        # RESET within 3 s of one request): ask again after a refusal, up to three times.
        for _ in range(3):
            setup.master.request_reset()
            if setup.run(WAIT / 3, lambda: any(
                    e.kind == SafetyKind.RESET for e in setup.events[count:]), commands):
                break
        assert any(e.kind == SafetyKind.RESET for e in setup.events[count:]), [
            e.text for e in setup.events[count:]]
        assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
            JOINTS, 'operation enabled'), commands)
    finally:
        setup.close()


def test_close_stops_the_motors_and_leaves_the_drives_disabled(setup):
    commands = dict.fromkeys(JOINTS, (120.0, True))
    setup.run(0.3, commands=commands)
    setup.master.close()
    assert not setup.master.running
    # Without the master's heartbeat the drives may act on the lost connection by now.
    assert all(state in ('switch on disabled', 'fault')
               for state in setup.rig_states().values()), setup.rig_states()
    deadline = time.monotonic() + WAIT
    while not setup.motors_stopped() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert setup.motors_stopped()


def test_start_names_the_devices_that_do_not_boot():
    setup = Setup(joints=('left_hip',))
    setup.master = Master(setup.bus, config(('left_hip', 'left_knee'), boot_timeout=0.3))
    try:
        with pytest.raises(CanOpenTimeoutError, match=r'no boot-up within 0.3 s .* left_knee '
                                                      r'drive \(node 2\), left_knee sensor '
                                                      r'board \(node 18\)'):
            setup.master.start()
    finally:
        setup.close()


def test_start_refuses_a_device_of_the_wrong_identity():
    setup = Setup(joints=('left_hip',))
    # The drive and the sensor board swapped: node 17 is a sensor board, not a drive.
    joint = joint_config('left_hip', drive_id=17, sensor_id=1)
    setup.master = Master(setup.bus, MasterConfig((joint,)))
    try:
        with pytest.raises(CanOpenError, match=r'node 17: identity 1018h sub 1/2 is vendor '
                                               r'0x000000AB, product 0x00002001; expected '
                                               r'vendor 0x000000AB, product 0x00001001'):
            setup.master.start()
    finally:
        setup.close()


def test_the_configuration_refuses_shared_node_ids_and_bad_times():
    with pytest.raises(HardwareConfigError, match='node IDs must differ'):
        MasterConfig((joint_config('left_hip'), joint_config('left_knee', drive_id=1)))
    with pytest.raises(HardwareConfigError, match=r'heartbeat_timeout 0\.05 s must exceed'):
        config(heartbeat_timeout=0.05)
    with pytest.raises(HardwareConfigError, match='missing_syncs = 0'):
        config(missing_syncs=0)
    with pytest.raises(HardwareConfigError, match="joint 'left_elbow' has no default node ID"):
        JointConfig.from_parameters('left_elbow', PARAMS['hip'])


def test_the_valve_mode_is_inferred_from_pressure_speed_and_drive_state():
    hip = joint_config('left_hip')  # relief 18 MPa, drop 0.2 MPa, release 0.5 rad/s
    enabled, off = cia402.OPERATION_ENABLED, cia402.SWITCH_ON_DISABLED
    assert infer_valve_mode(hip, enabled, 50.0, 18.0e6, 0.0) == ValveMode.RELIEF
    assert infer_valve_mode(hip, off, 0.0, 0.0, 18.5e6) == ValveMode.RELIEF
    assert infer_valve_mode(hip, off, 50.0, 5.0e6, 0.0) == ValveMode.FREE
    assert infer_valve_mode(hip, enabled, 0.1, 0.1e6, 0.0) == ValveMode.FREE
    # Stopped but loaded: the system pressure holds the spools in assist.
    assert infer_valve_mode(hip, enabled, 0.1, 2.0e6, 0.0) == ValveMode.ASSIST
    assert infer_valve_mode(hip, enabled, 30.0, 0.1e6, 0.0) == ValveMode.ASSIST
    assert infer_valve_mode(hip, enabled, -30.0, 17.9e6, 0.0) == ValveMode.ASSIST


def test_a_drive_sent_out_of_operational_is_started_again_and_quick_stopped(setup):
    commands = dict.fromkeys(JOINTS, (80.0, True))
    setup.run(0.3, commands=commands)
    drive = setup.rig.joint('left_hip').drive
    with setup.rig._lock:  # a drive that does nothing on a lost connection (6007h = 0)
        drive.values[(cd.ABORT_CONNECTION_OPTION_CODE, 0)] = cd.ABORT_CONNECTION_NO_ACTION
    other = can.Bus(interface='virtual', channel=setup.channel)
    try:
        other.send(can.Message(arbitration_id=cd.NMT_COB_ID, is_extended_id=False,
                               data=bytes((cd.NMT_ENTER_PRE_OPERATIONAL, drive.node_id))))
    finally:
        other.shutdown()
    event = setup.wait_event(SafetyKind.HEARTBEAT_LOST, commands=commands)
    assert event.joint == 'left_hip' and 'pre-operational' in event.text
    # The master starts it again, so that its quick stop applies: the motor stops.
    assert setup.run(WAIT, lambda: drive.nmt_state == cd.NMT_OPERATIONAL
                     and drive.state == 'switch on disabled' and setup.motors_stopped(),
                     commands), (drive.nmt_state, drive.state)
    # Its heartbeat reports operational within a producer period; until then resets fail.
    count = len(setup.events)
    deadline = time.monotonic() + WAIT
    while not any(e.kind == SafetyKind.RESET for e in setup.events[count:]):
        assert time.monotonic() < deadline, [e.text for e in setup.events[count:]]
        setup.master.request_reset()
        setup.run(0.2, commands=commands)
    assert setup.run(WAIT, lambda: drive.state == 'operation enabled', commands)


def test_a_drive_leaving_operation_enabled_by_itself_latches_a_drive_fault(setup):
    commands = dict.fromkeys(JOINTS, (60.0, True))
    setup.run(0.3, commands=commands)
    drive = setup.rig.joint('right_hip').drive
    with setup.rig._lock:
        drive._enter('switch on disabled')  # no EMCY, no fault: it just dropped out
    event = setup.wait_event(SafetyKind.DRIVE_FAULT, commands=commands)
    assert event.joint == 'right_hip'
    assert 'left operation enabled for switch on disabled by itself' in event.text
    assert setup.run(WAIT, setup.motors_stopped, commands)
    assert setup.run(0.3, lambda: drive.state == 'operation enabled', commands) is False


def test_a_drive_in_fault_without_emcy_right_after_the_start_is_not_reset_silently(setup):
    drive = setup.rig.joint('left_knee').drive
    with setup.rig._lock:
        drive._enter('fault')  # within the old 110 ms fault reset window, no EMCY
    event = setup.wait_event(SafetyKind.DRIVE_FAULT)
    assert event.joint == 'left_knee'
    assert event.text == ('left_knee drive (node 2) in fault (no EMCY received since it '
                          'entered fault)')
    setup.run(0.3)
    assert drive.state == 'fault'
    assert setup.master.latched


def test_a_command_faster_than_the_motor_is_clamped_to_its_maximum_speed(setup):
    setup.run(0.3, commands={'left_hip': (1000.0, True), 'left_knee': (-1000.0, True)})
    last = {s.joint: s for s in setup.samples}
    limit = PARAMS['hip'].motor_speed_max  # 4000 r/min
    quantum = 1.0 / setup.master.config.units.velocity_per_rad_s
    assert last['left_hip'].motor_speed_command == pytest.approx(limit, abs=quantum)
    assert last['left_knee'].motor_speed_command == pytest.approx(
        -PARAMS['knee'].motor_speed_max, abs=quantum)


def test_one_failed_receive_latches_a_bus_fault_and_the_master_keeps_running():
    setup = Setup(master_bus=FlakyBus)
    try:
        setup.master.start()
        commands = dict.fromkeys(JOINTS, (50.0, True))
        setup.run(0.2, commands=commands)
        setup.master.bus.fail_receives = 1
        event = setup.wait_event(SafetyKind.BUS_OFF, commands=commands)
        assert 'receiving from the CAN bus failed: could not unpack' in event.text
        setup.run(0.3, commands=commands)
        assert setup.master.running
        assert setup.master.failure is None
        # The fault holds for a second, then a reset is answered and releases.
        setup.run(1.0, commands=commands)
        count = len(setup.events)
        setup.master.request_reset()
        assert setup.run(WAIT, lambda: any(e.kind == SafetyKind.RESET
                                           for e in setup.events[count:]), commands), \
            [e.text for e in setup.events[count:]]
        assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
            JOINTS, 'operation enabled'), commands)
    finally:
        setup.close()


def test_a_bus_that_keeps_failing_to_receive_ends_the_master_with_its_failure():
    setup = Setup(master_bus=FlakyBus)
    try:
        setup.master.start()
        setup.master.bus.fail_receives = -1
        assert setup.run(WAIT + 2.0, lambda: not setup.master.running)
        assert isinstance(setup.master.failure, CanBusError)
        assert 'receives in a row failed' in str(setup.master.failure)
        assert setup.master.latched
        # Without SYNCs and the master's heartbeat the drives stop on their own.
        assert setup.run(WAIT, setup.motors_stopped)
    finally:
        setup.master.bus.fail_receives = 0
        setup.close()


def test_a_receive_error_at_start_is_a_can_bus_error():
    setup = Setup(joints=('left_hip',), master_bus=FlakyBus)
    try:
        setup.master.bus.fail_receives = -1
        with pytest.raises(CanBusError, match='the CAN bus failed while starting the slaves'):
            setup.master.start()
    finally:
        setup.master.bus.fail_receives = 0
        setup.close()


@pytest.mark.parametrize(('code', 'starts'), [(0x8130, True), (0x2310, False)])
def test_start_resets_only_a_lost_master_heartbeat_fault_and_names_any_other(code, starts):
    setup = Setup(joints=('left_hip', 'left_knee'))
    try:
        setup.rig.drive_fault('left_knee', code)
        if starts:
            setup.master.start()
            assert setup.master.drive_states() == dict.fromkeys(
                ('left_hip', 'left_knee'), cia402.OPERATION_ENABLED)
        else:
            with pytest.raises(CanOpenError, match=r'left_knee drive \(node 2\) is in fault with '
                                                   r'error code 0x2310 continuous over-current'):
                setup.master.start()
            assert setup.rig.joint('left_knee').drive.state == 'fault'
    finally:
        setup.close()


def test_start_waits_for_the_boot_up_not_any_heartbeat():
    setup = Setup(joints=('left_hip',))
    setup.master = Master(setup.bus, config(('left_hip',), boot_timeout=0.3))
    drive = setup.rig.joint('left_hip').drive
    on_nmt = drive.on_nmt

    def deaf_to_resets(data, now):
        if data[0] != cd.NMT_RESET_COMMUNICATION:
            on_nmt(data, now)

    drive.on_nmt = deaf_to_resets  # it keeps sending its pre-operational heartbeat
    try:
        with pytest.raises(CanOpenTimeoutError, match=r'no boot-up within 0.3 s .* left_hip '
                                                      r'drive \(node 1\)'):
            setup.master.start()
    finally:
        setup.close()


def test_the_configuration_refuses_a_rate_the_bus_cannot_carry():
    assert config(period=0.005).bitrate == 1_000_000  # 4 joints at 200 Hz: 44 %
    with pytest.raises(HardwareConfigError, match=r'the bus cannot carry a SYNC every 1 ms: '
                                                  r'4 joints take about 2135 bit per SYNC'):
        config(period=0.001)
    config(('left_hip',), period=0.001)  # one joint: 575 bit per ms
    with pytest.raises(HardwareConfigError, match='over 80% of 250 kbit/s'):
        config(bitrate=250_000)


def test_a_slave_that_rebooted_while_running_refuses_every_reset_until_the_restart(setup):
    other = can.Bus(interface='virtual', channel=setup.channel)
    try:
        other.send(can.Message(arbitration_id=cd.NMT_COB_ID, is_extended_id=False,
                               data=bytes((cd.NMT_RESET_NODE, 18))))
    finally:
        other.shutdown()
    event = setup.wait_event(SafetyKind.HEARTBEAT_LOST)
    assert event.text == ('left_knee sensor board (node 18): booted (boot-up message) while '
                          'running: its configuration is lost, restart the driver')
    # The latch starts it again (its TPDOs flow), but its configuration is the default one.
    assert setup.run(WAIT, lambda: setup.rig.joint('left_knee').board.nmt_state
                     == cd.NMT_OPERATIONAL)
    setup.run(0.3)
    count = len(setup.events)
    setup.master.request_reset()
    assert setup.run(WAIT, lambda: any(e.severity == Severity.WARN
                                       for e in setup.events[count:]))
    warning = next(e for e in setup.events[count:] if e.severity == Severity.WARN)
    assert 'restart the driver' in warning.text
    assert setup.master.latched


def test_a_slave_lost_now_and_then_is_one_condition_reported_when_it_starts_and_clears(setup):
    # The left hip's devices fall silent for 100 ms in every 160 ms: each gap is over the
    # missing SYNCs (10 at 5 ms) and under the heartbeat timeout (150 ms); gaps closer than
    # CLEAR_TIME are one condition, reported once, and cleared once after the last.
    commands = dict.fromkeys(JOINTS, (0.0, True))
    setup.run(0.2, commands=commands)
    for _ in range(5):
        setup.rig.set_silent('left_hip', True)
        setup.run(0.1, commands=commands)
        setup.rig.set_silent('left_hip', False)
        setup.run(0.06, commands=commands)
    setup.run(CLEAR_TIME + 0.25, commands=commands)
    missing = [e for e in setup.events if 'no TPDO' in e.text]
    assert [(e.severity, e.phase) for e in missing] == [(Severity.FATAL, Phase.START)] * 2 \
        + [(Severity.INFO, Phase.CLEAR)] * 2, [e.text for e in missing]
    assert {e.joint for e in missing} == {'left_hip'}
    assert all(e.text.startswith('cleared: ') for e in missing[2:])
    assert setup.master.latched  # cleared, not released: that takes a reset

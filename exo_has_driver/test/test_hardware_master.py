"""The CANopen master against the simulated devices (exo_has_driver.devices) on a virtual bus."""

import itertools
import math
import time
import uuid

import can
import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver import safety
from exo_has_driver.devices.rig import Rig
from exo_has_driver.errors import CanOpenError, CanOpenTimeoutError, HardwareConfigError
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.master import (
    JointConfig,
    Master,
    MasterConfig,
    infer_valve_mode,
)
from exo_has_sim.parameters import load_parameters

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
        return self._inner.recv(timeout), False

    def shutdown(self):
        """Close the inner bus."""
        self._inner.shutdown()
        super().shutdown()


class Setup:
    """A rig of simulated devices and a started master on one virtual bus."""

    def __init__(self, joints=JOINTS, master_bus=None, **settings):
        channel = f'test-{uuid.uuid4().hex}'
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

    def event_of(self, kind, severity=safety.SEVERITY_FATAL):
        """Return the first event of a kind and severity so far, or None."""
        return next((e for e in self.events if e.kind == kind and e.severity == severity),
                    None)

    def wait_event(self, kind, severity=safety.SEVERITY_FATAL, commands=None):
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
    setup.run(0.2)
    assert setup.events == []
    assert not setup.master.latched


def test_a_command_turns_the_motor_and_each_state_reports_it(setup):
    commands = dict.fromkeys(JOINTS, (-60.0, True))
    commands['left_knee'] = (40.0, True)
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
        assert last.valve_mode == safety.VALVE_ASSIST
        assert not last.sensor_fault
        plant = setup.rig.joint(joint).plant.sample()
        # The rig's plant moved on since the sample by at most a few SYNCs at ~0.03 m/s.
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
    assert last.valve_mode == safety.VALVE_FREE
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
    event = setup.wait_event(safety.KIND_E_STOP, commands=commands)
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
    event = setup.wait_event(safety.KIND_RESET, safety.SEVERITY_INFO)
    assert not event.latched
    assert 'latched by emergency stop: watchdog: tracking error' in event.text
    assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
        JOINTS, 'operation enabled'), commands)
    setup.run(0.3, commands=commands)
    assert setup.rig.joint('right_knee').plant.sample().motor_speed == pytest.approx(150.0,
                                                                                     abs=2.0)


def test_a_reset_without_a_latched_stop_says_so(setup):
    setup.master.request_reset()
    event = setup.wait_event(safety.KIND_RESET, safety.SEVERITY_INFO)
    assert event.text == 'reset: no stop was latched'


def inject_drive_fault(rig):
    rig.drive_fault('left_knee', 0x2310)


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
    'drive fault': (inject_drive_fault, safety.KIND_DRIVE_FAULT, 'left_knee', 0x2310, math.nan,
                    False),
    'lost heartbeat': (inject_lost_heartbeat, safety.KIND_HEARTBEAT_LOST, 'right_hip', None,
                       0.15, True),
    'sensor NaN': (inject_sensor_nan, safety.KIND_SENSOR_FAULT, 'left_hip', math.nan,
                   math.nan, True),
    'sensor out of range': (inject_sensor_out_of_range, safety.KIND_SENSOR_FAULT, 'right_knee',
                            PARAMS['knee'].stroke + 5e-3, PARAMS['knee'].stroke + 1e-3, True),
    'silent bus': (inject_silent_bus, safety.KIND_BUS_OFF, None, math.nan, math.nan, True),
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
            e.severity == safety.SEVERITY_WARN for e in setup.events[count:]), commands)
        warning = next(e for e in setup.events[count:] if e.severity == safety.SEVERITY_WARN)
        assert warning.latched and warning.text.startswith('reset refused: ')
        assert setup.master.latched
    setup.rig.clear()
    setup.run(0.4, commands=commands)  # heartbeats and TPDOs flow again
    count = len(setup.events)
    setup.master.request_reset()
    assert setup.run(WAIT, lambda: any(
        e.kind == safety.KIND_RESET for e in setup.events[count:]), commands), \
        [e.text for e in setup.events[count:]]
    reset = next(e for e in setup.events[count:] if e.kind == safety.KIND_RESET)
    assert (reset.severity, reset.latched) == (safety.SEVERITY_INFO, False)
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
        event = setup.wait_event(safety.KIND_BUS_OFF, commands=commands)
        assert event.latched
        expected = 'error passive' if breakage == 'error passive' else 'failed'
        assert expected in event.text
        if breakage == 'error passive':
            # The frames still flow: the drives are stopped.
            assert setup.run(WAIT, setup.motors_stopped, commands)
        count = len(setup.events)
        setup.master.request_reset()
        assert setup.run(WAIT, lambda: any(
            e.severity == safety.SEVERITY_WARN for e in setup.events[count:]), commands)
        bus.fake_state = can.BusState.ACTIVE
        bus.fail_sends = False
        setup.run(0.4, commands=commands)
        count = len(setup.events)
        setup.master.request_reset()
        assert setup.run(WAIT, lambda: any(
            e.kind == safety.KIND_RESET for e in setup.events[count:]), commands)
        assert setup.run(WAIT, lambda: setup.rig_states() == dict.fromkeys(
            JOINTS, 'operation enabled'), commands)
    finally:
        setup.close()


def test_close_stops_the_motors_and_leaves_the_drives_disabled(setup):
    commands = dict.fromkeys(JOINTS, (120.0, True))
    setup.run(0.3, commands=commands)
    setup.master.close()
    assert not setup.master.running
    assert setup.rig_states() == dict.fromkeys(JOINTS, 'switch on disabled')
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
    assert infer_valve_mode(hip, enabled, 50.0, 18.0e6, 0.0) == safety.VALVE_RELIEF
    assert infer_valve_mode(hip, off, 0.0, 0.0, 18.5e6) == safety.VALVE_RELIEF
    assert infer_valve_mode(hip, off, 50.0, 5.0e6, 0.0) == safety.VALVE_FREE
    assert infer_valve_mode(hip, enabled, 0.1, 0.1e6, 0.0) == safety.VALVE_FREE
    # Stopped but loaded: the system pressure holds the spools in assist.
    assert infer_valve_mode(hip, enabled, 0.1, 2.0e6, 0.0) == safety.VALVE_ASSIST
    assert infer_valve_mode(hip, enabled, 30.0, 0.1e6, 0.0) == safety.VALVE_ASSIST
    assert infer_valve_mode(hip, enabled, -30.0, 17.9e6, 0.0) == safety.VALVE_ASSIST

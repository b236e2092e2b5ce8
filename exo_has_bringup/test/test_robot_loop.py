"""The robot loop's core against a fake master, on a fake clock: safety, the law, the hold."""

from __future__ import annotations

import math

import pytest

from exo_has_bringup.robot_loop import GAP_CONDITION, LoopConfigError, LoopSettings, RobotLoop
from exo_has_bringup.robot_messages import (
    MAX_SAMPLES,
    BridgeStatus,
    EventMessage,
    GainChange,
    HeldConditions,
    LifecycleRequest,
    LoopMode,
    LoopState,
    Metrics,
    Reference,
    ResetRequest,
    States,
    Transition,
)
from exo_has_control.pd import PositionLoop, pd_command
from exo_has_control.tracking import ReferenceFollower
from exo_has_driver.events import Condition, Event, SafetyKind, Severity
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.config import JointSample
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters
from exo_has_sim.valve import ValveMode

JOINTS = ('left_hip', 'left_knee')
PARAMS = {joint: load_parameters(joint.rsplit('_', 1)[1]) for joint in JOINTS}
LINKAGES = {joint: Linkage.from_parameters(p) for joint, p in PARAMS.items()}
SETTINGS = LoopSettings(period=0.005, stale_periods=40, startup_grace=0.5)
PERIOD = SETTINGS.period
START = 100.0
PRESSURE = 2.0e6  # Pa: a working pressure, under every warning


class FakeMaster:
    """The master's caller side, with a stop latch that requests and held conditions set."""

    def __init__(self) -> None:
        self.latched = False
        self.samples: list[JointSample] = []
        self.events: list[Event] = []
        self.commands: dict[str, tuple[float, bool]] = {}
        self.stops: list[str] = []
        self.resets = 0
        self.held: list[object] = []
        self.cause: Event | None = None
        #: The master's SYNC grid: the due time of the cycle being run, and of the next.
        self.sync_due = math.nan
        self.next_sync = START + PERIOD
        #: Each drive's state; the enabled ones follow the commands when ``obey`` is set.
        self.states = dict.fromkeys(JOINTS, cia402.OPERATION_ENABLED)
        self.obey = True

    def all_enabled(self):
        """Whether every drive is in operation enabled."""
        return all(state == cia402.OPERATION_ENABLED for state in self.states.values())

    def drive_states(self):
        """Each drive's state."""
        return dict(self.states)

    def take_samples(self):
        """Return the samples set, once."""
        taken, self.samples = self.samples, []
        return taken

    def take_events(self):
        """Return the events set, once."""
        taken, self.events = self.events, []
        return taken

    def set_command(self, joint, motor_speed, enable, now=None):
        """Keep the newest command of a joint; a drive that obeys takes its enable."""
        self.commands[joint] = (motor_speed, enable)
        if self.obey:
            self.states[joint] = cia402.OPERATION_ENABLED if enable else \
                cia402.SWITCH_ON_DISABLED

    def request_stop(self, text):
        """Latch the stop, keeping its text."""
        self.stops.append(text)
        self.latched = True

    def request_reset(self):
        """Release the stop."""
        self.resets += 1
        self.latched = False

    def hold_conditions(self, conditions):
        """Keep the conditions; any latches the stop."""
        self.held = list(conditions)
        self.latched = self.latched or bool(conditions)


class FakeExchange:
    """The loop's end of the exchange as two lists."""

    def __init__(self) -> None:
        self.inbox: list[object] = []
        self.outbox: list[object] = []
        self.dropped = 0
        self.malformed = 0
        self.problem = ''

    def send(self, message):
        """Keep the message."""
        self.outbox.append(message)
        return True

    def receive(self):
        """Return the inbox, once."""
        taken, self.inbox = self.inbox, []
        return taken

    def events(self):
        """Return the events sent so far."""
        return [m.event for m in self.outbox if isinstance(m, EventMessage)]


class Rig:
    """A loop, its fake master and exchange, and the fake clock that drives its periods."""

    def __init__(self, settings: LoopSettings = SETTINGS, active: bool = True) -> None:
        self.master = FakeMaster()
        self.exchange = FakeExchange()
        self.t = START
        self.loop = RobotLoop(self.master, self.exchange, PARAMS, settings, START,
                              clock=lambda: self.t, cpu_clock=lambda: 0.0, active=active)
        self.requests = 0
        self.positions = {joint: PARAMS[joint].stroke / 2.0 for joint in JOINTS}
        self.counter = 0

    def sample(self, joint: str, position: float | None = None,
               pressure_a: float = PRESSURE) -> JointSample:
        """Return a sample of a joint at its position (or ``position``) now."""
        x = self.positions[joint] if position is None else position
        return JointSample(joint, self.t, x, 0.0, pressure_a, 0.3e6, 0.0, 0.0, 0.0,
                           ValveMode.ASSIST, cia402.OPERATION_ENABLED, False, self.counter)

    def period(self, *messages: object, samples: bool = True, **pressures: float) -> None:
        """Run one period: this period's samples and messages, then the cycle."""
        self.t += PERIOD
        self.counter += 1
        if samples:
            self.master.samples = [self.sample(joint, pressure_a=pressures.get(joint, PRESSURE))
                                   for joint in JOINTS]
        self.exchange.inbox = list(messages)
        master = self.master  # its grid, as Master._run keeps it: no burst after a hold-up
        master.sync_due = master.next_sync
        master.next_sync += PERIOD
        if master.next_sync < self.t:
            master.next_sync = self.t + PERIOD
        self.loop.cycle(self.t)

    def run(self, seconds: float, *messages: object) -> None:
        """Run periods for ``seconds``, each with the messages."""
        for _ in range(round(seconds / PERIOD)):
            self.period(*messages)

    def reference(self, angles: dict[str, float]) -> Reference:
        """Return a reference of the angles [rad] at rest, sent now."""
        return Reference(self.t, tuple(angles), tuple(angles.values()), (0.0,) * len(angles))

    def standing_angles(self, offset: float = 0.0) -> dict[str, float]:
        """Return the angles [rad] where the joints stand, plus ``offset``."""
        return {joint: float(LINKAGES[joint].angle_at(self.positions[joint])) + offset
                for joint in JOINTS}

    def transition(self, transition: Transition) -> LifecycleRequest:
        """Return a new lifecycle request."""
        self.requests += 1
        return LifecycleRequest(transition, self.requests)

    def answer(self, request: LifecycleRequest) -> LoopState | None:
        """Return the loop's answer to a request, None if none yet."""
        return next((m for m in self.exchange.outbox
                     if isinstance(m, LoopState) and m.request == request.request), None)

    def driven_toward(self, angles: dict[str, float]) -> bool:
        """Whether every joint is commanded, enabled, toward its angle [rad] of ``angles``."""
        return all(
            enable and speed * (float(LINKAGES[j].position_at(angles[j])) - self.positions[j]) > 0
            for j, (speed, enable) in self.master.commands.items())

    def events_of(self, kind: SafetyKind) -> list[Event]:
        """Return the events of a kind sent so far."""
        return [event for event in self.exchange.events() if event.kind == kind]


@pytest.fixture
def rig() -> Rig:
    return Rig()


def test_commands_are_the_pd_law_of_the_samples_and_the_reference(rig: Rig) -> None:
    # A joint the reference meets where it stands follows it at once (no rejoin ramp); the
    # loop's command is then exactly the law of exo_has_control.pd, one source.
    angles = rig.standing_angles()
    rig.period(rig.reference(angles))
    for step in range(1, 6):
        previous = dict(rig.positions)
        rig.positions = {joint: x + 1e-4 * step for joint, x in previous.items()}
        rig.period(rig.reference(angles))
        for joint in JOINTS:
            x_ref = float(LINKAGES[joint].position_at(angles[joint]))
            v = (rig.positions[joint] - previous[joint]) / PERIOD
            expected = pd_command(rig.loop.gains(joint), x_ref, 0.0, rig.positions[joint], v)
            speed, enable = rig.master.commands[joint]
            assert enable
            assert speed == pytest.approx(expected, rel=1e-12, abs=1e-9)
            assert speed < 0.0  # pushed off its reference: driven back


def test_commands_match_the_controller_nodes_law_while_rejoining_a_distant_reference(
        rig: Rig) -> None:
    # The same calls on a PositionLoop and a ReferenceFollower of their own, as the PD
    # controller node makes them, give the same commands, ramp included.
    angles = rig.standing_angles(offset=0.2)
    loop = PositionLoop(rig.loop.gains('left_hip'))
    follower = ReferenceFollower('left_hip', PARAMS['left_hip'], SETTINGS.reference_timeout,
                                 SETTINGS.rejoin_speed)
    for _ in range(50):
        rig.period(rig.reference(angles))
        follower.take(rig.t, tuple(angles), tuple(angles.values()), (0.0, 0.0))
        loop.measure(rig.t, rig.positions['left_hip'])
        x_ref, v_ref = follower.target(rig.t, rig.positions['left_hip'])
        assert rig.master.commands['left_hip'] == (loop.command(x_ref, v_ref), True)
    assert follower.rejoining  # 0.25 s at 15 mm/s is not enough to join 0.2 rad away


def test_a_stale_reference_holds_every_joint_and_only_a_reset_resumes(rig: Rig) -> None:
    angles = rig.standing_angles()
    rig.run(0.2, rig.reference(angles))
    assert not rig.loop.holding
    rig.run(SETTINGS.stale_time + 0.02)  # the bridge goes silent
    [hold] = rig.events_of(SafetyKind.STALE_REFERENCE)
    assert hold.severity == Severity.ERROR and hold.latched
    assert rig.loop.holding and not rig.loop.stopped
    # Held where they stand, under control: enabled, at rest where the samples are.
    assert rig.master.commands == dict.fromkeys(JOINTS, (0.0, True))
    # The reference comes back elsewhere: ignored until a reset.
    moved = rig.standing_angles(offset=0.3)
    rig.run(0.1, rig.reference(moved))
    assert rig.loop.holding
    assert rig.master.commands == dict.fromkeys(JOINTS, (0.0, True))
    rig.period(rig.reference(moved), ResetRequest())
    [reset] = rig.events_of(SafetyKind.RESET)
    assert not reset.latched and not rig.loop.holding
    rig.run(0.05, rig.reference(moved))
    for joint in JOINTS:
        speed, enable = rig.master.commands[joint]
        direction = math.copysign(1.0, LINKAGES[joint].position_at(moved[joint])
                                  - rig.positions[joint])
        assert enable and speed * direction > 0.0, (joint, speed)
    assert rig.master.stops == [] and rig.master.resets == 0


def test_a_reset_while_the_reference_is_still_stale_is_refused(rig: Rig) -> None:
    rig.run(0.1, rig.reference(rig.standing_angles()))
    rig.run(SETTINGS.stale_time + 0.02)
    rig.period(ResetRequest())
    [refusal] = [e for e in rig.exchange.events() if e.severity == Severity.WARN]
    assert refusal.kind == SafetyKind.STALE_REFERENCE and 'reset refused' in refusal.text
    assert rig.loop.holding


def test_a_reference_whose_publisher_left_is_withdrawn_without_a_hold(rig: Rig) -> None:
    rig.run(0.1, rig.reference(rig.standing_angles()), BridgeStatus(True))
    rig.run(SETTINGS.stale_time + 0.05, BridgeStatus(False))
    assert rig.events_of(SafetyKind.STALE_REFERENCE) == []
    assert not rig.loop.holding


def test_a_fatal_of_the_safety_core_stops_every_joint_until_a_reset(rig: Rig) -> None:
    rig.run(0.1, rig.reference(rig.standing_angles()))
    relief = PARAMS['left_knee'].relief_pressure
    rig.period(rig.reference(rig.standing_angles()), left_knee=relief)
    [fatal] = [e for e in rig.exchange.events() if e.severity == Severity.FATAL]
    assert fatal.kind == SafetyKind.SAFETY_VALVE_OPEN and fatal.joint == 'left_knee'
    assert rig.master.stops == [fatal.text]  # the master quick-stops every drive
    assert rig.master.commands == dict.fromkeys(JOINTS, (0.0, False))
    # Refused while the valve is still open; every joint stays stopped.
    rig.period(rig.reference(rig.standing_angles()), ResetRequest(), left_knee=relief)
    assert rig.loop.stopped and rig.master.resets == 0
    rig.run(0.3, rig.reference(rig.standing_angles()))
    assert rig.loop.stopped
    assert rig.master.commands == dict.fromkeys(JOINTS, (0.0, False))
    rig.period(rig.reference(rig.standing_angles()), ResetRequest())
    assert rig.master.resets == 1 and not rig.loop.stopped
    rig.period(rig.reference(rig.standing_angles()))
    assert all(enable for _, enable in rig.master.commands.values())


def test_a_stop_latched_by_the_master_disables_every_command_until_it_is_released(
        rig: Rig) -> None:
    rig.run(0.1, rig.reference(rig.standing_angles()))
    rig.master.latched = True  # a drive fault, say
    rig.period(rig.reference(rig.standing_angles()))
    assert rig.master.commands == dict.fromkeys(JOINTS, (0.0, False))
    rig.period(rig.reference(rig.standing_angles()), ResetRequest())  # forwarded to the master
    assert rig.master.resets == 1
    rig.period(rig.reference(rig.standing_angles()))
    assert all(enable for _, enable in rig.master.commands.values())


def test_a_gap_over_the_missed_limit_latches_a_fatal_naming_its_cause(rig: Rig) -> None:
    rig.run(0.05, rig.reference(rig.standing_angles()))
    rig.t += 15 * PERIOD  # the thread held off for 15 periods
    rig.period(rig.reference(rig.standing_angles()))
    [condition] = rig.master.held
    assert condition.key == GAP_CONDITION and condition.kind == SafetyKind.STALE_COMMAND
    assert condition.value == pytest.approx(16 * PERIOD)
    assert condition.limit == pytest.approx(SETTINGS.gap_limit)
    assert '15 missed' in condition.text and 'held off the CPU' in condition.text
    assert 'default scheduler' in condition.text
    assert rig.master.latched
    rig.period(rig.reference(rig.standing_angles()))
    assert rig.master.held == []  # reported once; the latch holds until a reset
    assert rig.loop.monitor.missed == 15
    assert rig.loop.longest_gap == pytest.approx(16 * PERIOD)


def test_a_gap_within_the_limit_counts_missed_periods_and_stops_nothing(rig: Rig) -> None:
    rig.run(0.05, rig.reference(rig.standing_angles()))
    rig.t += 3 * PERIOD
    rig.period(rig.reference(rig.standing_angles()))
    assert rig.master.held == [] and not rig.loop.stopped
    assert rig.loop.monitor.missed == 3


def test_after_a_hold_up_the_periods_on_the_masters_new_grid_are_not_late(rig: Rig) -> None:
    # The master sends the SYNC after a hold-up a period after it ran, not on the old grid.
    rig.run(0.05, rig.reference(rig.standing_angles()))
    rig.t += 2.3 * PERIOD
    rig.run(0.5, rig.reference(rig.standing_angles()))
    monitor = rig.loop.monitor
    assert monitor.missed == 2 and monitor.late == 0
    assert monitor.lateness_percentile(99.0) <= 1e-4  # the first bin: on time


def test_states_events_and_metrics_go_to_the_bridge(rig: Rig) -> None:
    rig.run(0.25, rig.reference(rig.standing_angles()))
    states = [m for m in rig.exchange.outbox if isinstance(m, States)]
    assert len(states) == 50 and {s.joint for s in states[-1].samples} == set(JOINTS)
    metrics = [m for m in rig.exchange.outbox if isinstance(m, Metrics)]
    assert len(metrics) == 3  # at 0, 0.1 and 0.2 s
    last = metrics[-1]
    assert last.periods == round((last.t - START) / PERIOD) and last.missed == 0
    assert last.longest_gap == pytest.approx(PERIOD) and last.lateness_max == 0.0
    assert not last.stopped and not last.holding


def test_a_backlog_of_samples_goes_to_the_bridge_in_messages_of_bounded_size(rig: Rig) -> None:
    rig.master.samples = [rig.sample('left_hip') for _ in range(70)]
    rig.period(samples=False)
    sizes = [len(m.samples) for m in rig.exchange.outbox if isinstance(m, States)]
    assert sizes == [MAX_SAMPLES, MAX_SAMPLES, 70 - 2 * MAX_SAMPLES]


def test_a_gain_change_applies_from_the_next_period_and_an_invalid_one_is_refused(
        rig: Rig) -> None:
    rig.period(GainChange('knee', 50e3, 10.0, 0.0, 300.0))
    gains = rig.loop.gains('left_knee')
    assert (gains.kp, gains.kd, gains.kff, gains.speed_limit) == (50e3, 10.0, 0.0, 300.0)
    assert rig.loop.gains('left_hip').kp == 35e3
    rig.period(GainChange('hip', -1.0, 10.0, 0.0, 300.0))
    assert rig.loop.gains('left_hip').kp == 35e3
    assert 'hip gain change refused' in rig.loop.problem
    rig.period(GainChange('hip', 35e3, 15.0, 0.0, 1e6))
    assert 'over the motor top speed' in rig.loop.problem
    assert rig.loop.gains('left_hip').speed_limit == PARAMS['left_hip'].motor_speed_max


@pytest.mark.parametrize(('setting', 'value'), [('period', 0.0), ('stale_periods', 0),
                                                ('missed_limit', 1.5), ('startup_grace', -1.0)])
def test_a_setting_out_of_range_is_refused_naming_it(setting: str, value: float) -> None:
    with pytest.raises(LoopConfigError, match=setting):
        LoopSettings(**{setting: value})


def test_an_inactive_loop_keeps_the_drives_disabled_and_ignores_references() -> None:
    rig = Rig(active=False)
    rig.run(0.5, rig.reference(rig.standing_angles(offset=0.1)))
    assert all(command == (0.0, False) for command in rig.master.commands.values())
    assert rig.exchange.events() == []  # no reference judged: none is stale, none tracked
    reports = [m for m in rig.exchange.outbox if isinstance(m, LoopState)]
    assert reports and all(m == LoopState(LoopMode.INACTIVE, 0, True) for m in reports)


def test_an_activation_answers_once_every_drive_is_enabled_then_the_loop_follows() -> None:
    rig = Rig(active=False)
    rig.period()
    rig.master.obey = False  # the drives take three periods to enable
    activate = rig.transition(Transition.ACTIVATE)
    rig.period(activate)
    assert all(command == (0.0, True) for command in rig.master.commands.values())
    rig.run(2 * PERIOD)
    assert rig.answer(activate) is None and rig.loop.mode is LoopMode.INACTIVE
    rig.master.states = dict.fromkeys(JOINTS, cia402.OPERATION_ENABLED)
    rig.period()
    assert rig.answer(activate) == LoopState(LoopMode.ACTIVE, activate.request, True)
    angles = rig.standing_angles(offset=0.05)
    rig.run(0.2, rig.reference(angles))
    assert rig.driven_toward(angles)


def test_an_activation_the_drives_do_not_follow_is_refused_naming_their_states() -> None:
    rig = Rig(active=False)
    rig.master.obey = False
    rig.master.states['left_knee'] = cia402.FAULT
    activate = rig.transition(Transition.ACTIVATE)
    rig.period(activate)
    rig.run(SETTINGS.enable_timeout + 2 * PERIOD)
    answer = rig.answer(activate)
    assert answer is not None and not answer.ok and answer.mode is LoopMode.INACTIVE
    assert 'left_knee drive in fault' in answer.text, answer.text
    assert 'left_hip' not in answer.text
    assert all(command == (0.0, False) for command in rig.master.commands.values())


def test_an_activation_under_a_latched_stop_is_refused_naming_the_stop() -> None:
    rig = Rig(active=False)
    rig.master.latched = True
    rig.master.cause = Event('left_hip', SafetyKind.DRIVE_FAULT, Severity.FATAL, 0x7121,
                             math.nan, True, 'left_hip drive fault 0x7121 (motor blocked)')
    activate = rig.transition(Transition.ACTIVATE)
    rig.period(activate)
    answer = rig.answer(activate)
    assert answer is not None and not answer.ok
    assert 'left_hip drive fault 0x7121' in answer.text and 'reset it first' in answer.text


def test_a_deactivation_holds_every_joint_under_control_and_a_reactivation_rejoins(
        rig: Rig) -> None:
    angles = rig.standing_angles()
    rig.run(0.2, rig.reference(angles))
    deactivate = rig.transition(Transition.DEACTIVATE)
    rig.period(rig.reference(angles), deactivate)
    assert rig.answer(deactivate) == LoopState(LoopMode.INACTIVE, deactivate.request, True)
    # Pushed off where it stood, each joint is driven back, a moved reference ignored, and
    # the silence of the reference is no stale reference.
    held = rig.standing_angles()
    rig.positions = {joint: x + 1e-3 for joint, x in rig.positions.items()}
    rig.run(SETTINGS.stale_time * 2, rig.reference(rig.standing_angles(offset=0.3)))
    assert rig.driven_toward(held)
    assert rig.events_of(SafetyKind.STALE_REFERENCE) == []
    assert not rig.loop.holding  # the safety core holds nothing: no reset is needed
    activate = rig.transition(Transition.ACTIVATE)
    rig.period(activate)
    assert rig.answer(activate) == LoopState(LoopMode.ACTIVE, activate.request, True)
    far = rig.standing_angles(offset=0.3)
    rig.run(0.1, rig.reference(far))
    assert rig.driven_toward(far)


def test_a_cleanup_is_refused_while_active_and_once_inactive_disables_the_drives(
        rig: Rig) -> None:
    rig.period()
    cleanup = rig.transition(Transition.CLEANUP)
    rig.period(cleanup)
    answer = rig.answer(cleanup)
    assert answer is not None and not answer.ok and 'deactivate it' in answer.text
    assert rig.loop.cleanup_request == 0
    rig.period(rig.transition(Transition.DEACTIVATE))
    cleanup = rig.transition(Transition.CLEANUP)
    rig.period(cleanup)
    assert rig.loop.cleanup_request == cleanup.request and rig.answer(cleanup) is None
    assert all(command == (0.0, False) for command in rig.master.commands.values())


def test_cycles_late_on_the_masters_grid_are_late_from_the_first_one_on(rig: Rig) -> None:
    # Every cycle runs 2 ms after its SYNC was due (a thread woken late each time): the
    # lateness is the master's, not that of a grid begun at the loop's own first cycle.
    rig.master.next_sync -= 0.002
    rig.run(0.5, rig.reference(rig.standing_angles()))
    monitor = rig.loop.monitor
    assert monitor.missed == 0
    assert monitor.lateness_percentile(99.0) == pytest.approx(0.002, abs=1.5e-4)  # a 0.1 ms bin


def test_the_bridges_conditions_are_held_beside_the_loops_own_until_it_clears_them(
        rig: Rig) -> None:
    second = Condition('/left_hip/has_command', 'left_hip', SafetyKind.SECOND_SOURCE, 2.0, 1.0,
                       'left_hip: second source: 2 publishers on /left_hip/has_command '
                       '(/pd_controller, the robot loop)')
    rig.run(0.05, rig.reference(rig.standing_angles()))
    rig.period(HeldConditions((second,)))
    [held] = rig.master.held
    assert held.key == ('bridge', '/left_hip/has_command') and held.text == second.text
    assert rig.master.latched
    rig.t += 15 * PERIOD  # a gap too: both are held, neither replaces the other
    rig.period(HeldConditions((second,)))
    assert [c.key for c in rig.master.held] == [GAP_CONDITION, held.key]
    rig.period(HeldConditions(()))
    assert rig.master.held == []

import math

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from exo_has_common.joints import JOINT_NAMES
from exo_has_driver import joint_watch
from exo_has_driver.errors import SafetyConfigError
from exo_has_driver.events import CLEAR_TIME, Phase, SafetyKind, Severity
from exo_has_driver.joint_watch import LEVEL_ERROR, LEVEL_OK, LEVEL_STALE, LEVEL_WARN
from exo_has_driver.safety import Watchdog
from exo_has_driver.safety_limits import SafetyLimits
from exo_has_msgs.msg import HasState, SafetyEvent
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters
from exo_has_sim.valve import ValveMode

PARAMS = {'hip': load_parameters('hip'), 'knee': load_parameters('knee')}
LINKAGE = {kind: Linkage.from_parameters(params) for kind, params in PARAMS.items()}
PERIOD = 0.005  # s, the 200 Hz control period
STROKE = PARAMS['hip'].stroke  # m, the same cylinder at every joint (one module)
assert PARAMS['knee'].stroke == STROKE
MID = 0.5 * STROKE  # m
RELIEF = 18.0e6  # Pa, both parameter sets


def kind_of(joint):
    return 'hip' if joint.endswith('hip') else 'knee'


def make_watchdog(start=0.0, **options):
    limits = {joint: SafetyLimits.from_parameters(PARAMS[kind_of(joint)], **options)
              for joint in JOINT_NAMES}
    return Watchdog(limits, start)


def feed(watchdog, t, skip=(), position=MID, pressure_a=5.0e6, pressure_b=1.0e6,
         valve_mode=ValveMode.ASSIST):
    """Send one period of normal states and enabled commands, then check; return the events."""
    events = []
    for joint in JOINT_NAMES:
        if joint not in skip:
            events += watchdog.on_state(joint, t, position, pressure_a, pressure_b, valve_mode)
            events += watchdog.on_command(joint, t, 10.0, True)
    return events + watchdog.check(t)


def running(until=0.1, **options):
    """Return a watchdog that has seen normal traffic up to ``until`` [s], and ``until``."""
    watchdog = make_watchdog(**options)
    for t in np.arange(0.0, until, PERIOD):
        assert feed(watchdog, t) == []
    return watchdog, until


def only(events):
    assert len(events) == 1, events
    return events[0]


def test_kinds_severities_valve_modes_and_levels_are_numbered_as_the_messages():
    def constants(message, prefix):
        return {name[len(prefix):]: getattr(message, name) for name in dir(message)
                if name.startswith(prefix)}
    # Both ways: every constant has its member and every member its constant, of one value.
    assert {kind.name: kind.value for kind in SafetyKind} == constants(SafetyEvent, 'KIND_')
    assert {s.name: s.value for s in Severity} == constants(SafetyEvent, 'SEVERITY_')
    assert {p.name: p.value for p in Phase} == constants(SafetyEvent, 'PHASE_')
    assert {mode.name: mode.value for mode in ValveMode} == constants(HasState, 'VALVE_')
    assert SafetyKind.SAFETY_VALVE_OPEN.label == 'safety valve open'
    assert SafetyKind.OVER_PRESSURE.label == 'over-pressure'
    assert SafetyKind.E_STOP.label == 'emergency stop'
    # The core's levels are ints; the message's byte constants are one byte each in rclpy.
    for name in ('OK', 'WARN', 'ERROR', 'STALE'):
        assert bytes([getattr(joint_watch, f'LEVEL_{name}')]) == getattr(DiagnosticStatus, name)


def test_limits_come_from_the_parameter_sets_and_the_control_period():
    limits = SafetyLimits.from_parameters(PARAMS['hip'])
    assert limits.relief_pressure == RELIEF
    assert limits.warning_pressure == pytest.approx(16.2e6)
    assert limits.stroke == STROKE
    assert limits.state_timeout == limits.command_timeout == pytest.approx(0.05)
    assert limits.tracking_error_limit == pytest.approx(math.radians(20.0))
    slow = SafetyLimits.from_parameters(PARAMS['knee'], stale_periods=4, control_rate=100.0)
    assert slow.state_timeout == pytest.approx(0.04)


@pytest.mark.parametrize(('option', 'value', 'named'), [
    ('over_pressure_ratio', 1.5, 'over_pressure_ratio = 1.5 must be in (0, 1]'),
    ('stale_periods', 0, 'stale_periods = 0 must be an integer'),
    ('control_rate', 0.0, 'control_rate = 0.0 must be positive'),
    ('stroke_margin', 0.05, 'stroke_margin = 0.05 must be in [0, stroke / 4'),
    ('tracking_error_limit', -0.1, 'tracking_error_limit = -0.1 must be positive'),
    ('startup_grace', math.nan, 'startup_grace = nan must be a finite number'),
])
def test_a_setting_out_of_range_fails_naming_it(option, value, named):
    with pytest.raises(SafetyConfigError, match=named.replace('(', r'\(').replace('[', r'\[')):
        SafetyLimits.from_parameters(PARAMS['hip'], **{option: value})


def test_an_unknown_joint_is_refused_naming_the_watched_ones():
    watchdog = make_watchdog()
    with pytest.raises(SafetyConfigError, match="'left_ankle' is not watched: watched are "
                                                'left_hip, left_knee'):
        watchdog.on_state('left_ankle', 0.0, MID, 0.0, 0.0, ValveMode.ASSIST)


def test_a_plausible_squatting_session_raises_no_event():
    # The paper's squat (hip 40 deg, knee 70 deg at 0.5 Hz) tracked with a 30 ms lag and the
    # paper's worst offsets (+2.5 deg left, -1.5 deg right), pressures up to 14 MPa.
    watchdog = make_watchdog()
    depth = {'hip': math.radians(40.0), 'knee': math.radians(70.0)}
    offset = {'left': math.radians(2.5), 'right': math.radians(-1.5)}
    events = []
    for t in np.arange(0.0, 6.0, PERIOD):
        def reference(joint, at):
            return depth[kind_of(joint)] * 0.5 * (1.0 - math.cos(math.pi * max(at, 0.0)))
        events += watchdog.on_reference(t, {j: reference(j, t) for j in JOINT_NAMES})
        for joint in JOINT_NAMES:
            angle = reference(joint, t - 0.03) + offset[joint.split('_')[0]]
            position = float(LINKAGE[kind_of(joint)].position(angle))
            pressure = 8.0e6 + 6.0e6 * math.sin(2.0 * math.pi * 0.5 * t)
            events += watchdog.on_state(joint, t, position, pressure, 0.3e6, ValveMode.ASSIST)
            events += watchdog.on_command(joint, t, 150.0 * math.sin(math.pi * t), True)
        events += watchdog.check(t)
    assert events == []
    assert all(d.level == LEVEL_OK and d.message == 'ok' for d in watchdog.diagnostics(6.0))


@pytest.mark.parametrize(('pressure_a', 'pressure_b', 'valve_mode', 'value'), [
    (RELIEF, 1.0e6, ValveMode.ASSIST, RELIEF),
    (0.2e6, 18.3e6, ValveMode.ASSIST, 18.3e6),
    (12.0e6, 0.5e6, ValveMode.RELIEF, 12.0e6),
])
def test_an_open_safety_valve_is_fatal_once_and_latches(pressure_a, pressure_b, valve_mode,
                                                         value):
    watchdog, t = running()
    event = only(watchdog.on_state('left_knee', t, MID, pressure_a, pressure_b, valve_mode))
    assert (event.joint, event.kind, event.severity) == ('left_knee', SafetyKind.SAFETY_VALVE_OPEN,
                                                         Severity.FATAL)
    assert (event.value, event.limit, event.latched) == (value, RELIEF, True)
    assert 'safety valve open' in event.text and watchdog.stopped
    assert watchdog.cause == event
    for step in range(1, 20):  # persisting: not reported again, and no over-pressure beside it
        assert watchdog.on_state('left_knee', t + step * PERIOD, MID, pressure_a, pressure_b,
                                 valve_mode) == []


def test_over_pressure_warns_once_reports_when_it_has_cleared_and_warns_anew_after():
    watchdog, t = running()
    # Down under the hysteresis (15.0 MPa) and back within CLEAR_TIME: one condition.
    pressures = [16.5e6, 16.6e6, 16.0e6, 17.0e6, 15.0e6, 16.4e6]
    raised = [watchdog.on_state('right_hip', t + i * PERIOD, MID, p, 0.0, ValveMode.ASSIST)
              for i, p in enumerate(pressures)]
    assert [len(events) for events in raised] == [1, 0, 0, 0, 0, 0]
    event = raised[0][0]
    assert (event.kind, event.severity, event.value) == (SafetyKind.OVER_PRESSURE, Severity.WARN,
                                                         16.5e6)
    assert event.limit == pytest.approx(0.9 * RELIEF) and not event.latched
    assert event.phase == Phase.START
    assert not watchdog.stopped
    # Then away for CLEAR_TIME: reported cleared once, and a new one is a new condition.
    start = t + len(pressures) * PERIOD
    steps = round(CLEAR_TIME / PERIOD) + 2
    events = [e for k in range(steps) for e in feed(watchdog, start + k * PERIOD)]
    cleared = only(events)
    assert (cleared.joint, cleared.kind, cleared.severity, cleared.phase) == (
        'right_hip', SafetyKind.OVER_PRESSURE, Severity.INFO, Phase.CLEAR)
    assert cleared.text == 'right_hip: over-pressure cleared' and not cleared.latched
    again = only(watchdog.on_state('right_hip', start + steps * PERIOD, MID, 16.5e6, 0.0,
                                   ValveMode.ASSIST))
    assert (again.kind, again.phase) == (SafetyKind.OVER_PRESSURE, Phase.START)


def test_a_condition_that_comes_and_goes_between_samples_of_two_sources_is_one_event():
    # A second plant at a stroke end beside the real one at mid stroke, states interleaved.
    watchdog, t = running()
    events = []
    for k in range(200):
        position = STROKE - 0.0001 if k % 2 else MID
        events += watchdog.on_state('left_knee', t + k * PERIOD / 2, position, 5.0e6, 1.0e6,
                                    ValveMode.ASSIST)
        if k % 2:
            events += watchdog.check(t + k * PERIOD / 2)
    strokes = [e for e in events if e.kind == SafetyKind.STROKE_END]
    assert len(strokes) == 1 and strokes[0].phase == Phase.START


def test_two_sources_at_the_two_stroke_ends_give_a_start_and_one_change_not_one_a_sample():
    # A stopped knee sinks to one end while a second plant stands at the other (measured: a
    # session with a stray plant gave 118 change events in 4 s before this rule).
    watchdog, t = running()
    events = []
    for k in range(200):
        position = STROKE - 0.0001 if k % 2 else 0.0001
        at = t + k * PERIOD / 2
        events += watchdog.on_state('left_knee', at, position, 5.0e6, 1.0e6, ValveMode.ASSIST)
        events += watchdog.check(at)
    strokes = [(e.phase, e.limit) for e in events if e.kind == SafetyKind.STROKE_END]
    assert strokes == [(Phase.START, 0.0), (Phase.CHANGE, STROKE)]


def test_reaching_a_stroke_end_is_an_error_once_and_the_other_end_a_change():
    watchdog, t = running()
    # Near the extended end (within the 0.5 mm margin), back in, near the retracted end, back.
    positions = [STROKE - 0.0003, STROKE - 0.0001, STROKE - 0.0002, STROKE - 0.01, 0.0004,
                 0.0001, MID]
    raised = [watchdog.on_state('left_hip', t + i * PERIOD, x, 5.0e6, 1.0e6, ValveMode.ASSIST)
              for i, x in enumerate(positions)]
    assert [len(events) for events in raised] == [1, 0, 0, 0, 1, 0, 0]
    extended, retracted = raised[0][0], raised[4][0]
    assert (extended.kind, extended.severity) == (SafetyKind.STROKE_END, Severity.ERROR)
    assert (extended.value, extended.limit) == (pytest.approx(STROKE - 0.0003), STROKE)
    assert (retracted.value, retracted.limit) == (0.0004, 0.0)
    # The other end within CLEAR_TIME of the first: the condition changed, it did not end.
    assert (extended.phase, retracted.phase) == (Phase.START, Phase.CHANGE)
    assert not watchdog.stopped


def tracking_states(watchdog, joint, start, duration, error):
    """Feed states of ``joint`` off a mid-range reference by ``error`` [rad]; return events."""
    reference = {'hip': 0.3, 'knee': 0.6}[kind_of(joint)]
    position = float(LINKAGE[kind_of(joint)].position(reference - error))
    events = []
    for t in np.arange(start, start + duration, PERIOD):
        events += watchdog.on_reference(t, {joint: reference})
        events += watchdog.on_state(joint, t, position, 5.0e6, 1.0e6, ValveMode.ASSIST)
    return events


def test_a_tracking_error_over_the_limit_is_fatal_only_when_it_persists():
    watchdog, t = running(startup_grace=0.0)  # judged from the first reference on
    assert tracking_states(watchdog, 'right_knee', t, 0.15, 0.4) == []  # too short
    assert tracking_states(watchdog, 'right_knee', t + 0.15, 0.05, 0.1) == []  # back in
    event = only(tracking_states(watchdog, 'right_knee', t + 0.2, 0.5, -0.4))
    assert (event.joint, event.kind, event.severity) == ('right_knee', SafetyKind.TRACKING_ERROR,
                                                         Severity.FATAL)
    assert event.value == pytest.approx(0.4)
    assert event.limit == pytest.approx(math.radians(20.0))
    assert 'for 0.200 s' in event.text and event.latched


def test_a_disabled_drive_is_not_held_to_its_reference():
    watchdog, t = running(startup_grace=0.0)
    watchdog.on_command('left_hip', t, 0.0, False)
    assert tracking_states(watchdog, 'left_hip', t, 0.5, 0.5) == []
    assert not watchdog.stopped


def test_a_joint_whose_node_died_goes_stale_once():
    watchdog, t = running()
    events = []
    for step in range(40):  # left_hip's plant and controller are gone; the others run on
        events += feed(watchdog, t + step * PERIOD, skip=('left_hip',))
    stale_state, stale_command = events
    assert (stale_state.joint, stale_state.kind, stale_state.severity) == (
        'left_hip', SafetyKind.STALE_STATE, Severity.FATAL)
    assert stale_state.limit == pytest.approx(0.05)
    assert 0.05 < stale_state.value <= 0.05 + PERIOD + 1e-9
    assert stale_state.latched and watchdog.stopped
    # In the same check: not yet stopped then.
    assert stale_command.kind == SafetyKind.STALE_COMMAND


def test_nothing_at_all_within_the_startup_grace_is_stale():
    watchdog = make_watchdog(start=100.0, startup_grace=2.0)
    assert watchdog.check(101.9) == []
    events = watchdog.check(102.1)
    assert {(e.joint, e.kind) for e in events} == {
        (j, k) for j in JOINT_NAMES for k in (SafetyKind.STALE_STATE, SafetyKind.STALE_COMMAND)}
    assert events[0].value == pytest.approx(2.1) and events[0].limit == 2.0
    assert watchdog.check(102.2) == []


@pytest.mark.parametrize('speed', [math.nan, math.inf, -math.inf])
def test_a_nan_or_infinite_command_is_an_invalid_command(speed):
    watchdog, t = running()
    event = only(watchdog.on_command('right_knee', t, speed, True))
    assert (event.kind, event.severity, event.latched) == (SafetyKind.INVALID_COMMAND,
                                                          Severity.FATAL, True)
    assert math.isnan(event.limit) and (event.value == speed or math.isnan(event.value))


@pytest.mark.parametrize(('position', 'pressure_a', 'pressure_b', 'valve_mode', 'limit'), [
    (math.nan, 5.0e6, 1.0e6, ValveMode.ASSIST, math.nan),
    (MID, math.inf, 1.0e6, ValveMode.ASSIST, math.nan),
    (MID, 5.0e6, math.nan, ValveMode.ASSIST, math.nan),
    (STROKE + 0.01, 5.0e6, 1.0e6, ValveMode.ASSIST, STROKE + 0.002),
    (MID, -0.5e6, 1.0e6, ValveMode.ASSIST, -0.12e6),
    (MID, 5.0e6, 1.0e6, 7, 2.0),
])
def test_an_impossible_state_value_is_a_sensor_fault(position, pressure_a, pressure_b,
                                                      valve_mode, limit):
    watchdog, t = running()
    event = only(watchdog.on_state('left_knee', t, position, pressure_a, pressure_b,
                                   valve_mode))
    assert (event.kind, event.severity) == (SafetyKind.SENSOR_FAULT, Severity.FATAL)
    assert event.limit == pytest.approx(limit, nan_ok=True)
    assert watchdog.on_state('left_knee', t, position, pressure_a, pressure_b,
                             valve_mode) == []


def test_while_stopped_commands_are_ignored_but_new_fatal_conditions_are_reported():
    watchdog, t = running()
    only(watchdog.on_command('left_hip', t, math.nan, True))
    assert watchdog.on_command('left_hip', t, math.nan, True) == []  # a stop command now
    events = []
    for step in range(1, 100):  # states flow, no command at all: no stale command
        events += feed(watchdog, t + step * PERIOD, skip=JOINT_NAMES)
        for joint in JOINT_NAMES:
            events += watchdog.on_state(joint, t + step * PERIOD, MID, 5.0e6, 1.0e6,
                                        ValveMode.ASSIST)
    assert events == []
    event = only(watchdog.on_state('right_hip', t + 0.5, MID, RELIEF, 0.0, ValveMode.RELIEF))
    assert event.kind == SafetyKind.SAFETY_VALVE_OPEN and event.latched
    assert watchdog.cause.kind == SafetyKind.INVALID_COMMAND  # the first cause is kept


def test_a_reset_is_refused_while_a_fatal_condition_holds_and_releases_the_latch_after():
    watchdog, t = running()
    only(watchdog.on_state('left_knee', t, MID, RELIEF, 0.0, ValveMode.RELIEF))
    refused = only(watchdog.reset(t + 0.001))
    assert (refused.joint, refused.kind, refused.severity, refused.latched) == (
        'left_knee', SafetyKind.SAFETY_VALVE_OPEN, Severity.WARN, True)  # not RESET: none released
    assert (refused.value, refused.limit) == (RELIEF, RELIEF)
    assert 'reset refused: left_knee: safety valve still open' in refused.text
    assert watchdog.stopped
    assert feed(watchdog, t + 0.002) == []  # the pressure is down again
    released = only(watchdog.reset(t + 0.003))
    assert (released.joint, released.kind, released.severity, released.latched) == (
        '', SafetyKind.RESET, Severity.INFO, False)
    assert 'stop released (latched by left_knee: safety valve open' in released.text
    assert not watchdog.stopped and watchdog.cause is None
    assert math.isnan(released.value) and math.isnan(released.limit)


def test_a_reset_is_refused_while_a_joint_is_still_stale():
    watchdog, t = running()
    events = []
    for step in range(20):
        events += feed(watchdog, t + step * PERIOD, skip=('right_knee',))
    assert {e.kind for e in events} == {SafetyKind.STALE_STATE, SafetyKind.STALE_COMMAND}
    refused = only(watchdog.reset(t + 0.1))
    assert (refused.joint, refused.kind, refused.severity) == (
        'right_knee', SafetyKind.STALE_STATE, Severity.WARN)
    assert refused.value == pytest.approx(0.105) and refused.limit == 0.05  # since 0.095 s
    assert 'reset refused: right_knee: no state for 0.1' in refused.text
    assert feed(watchdog, t + 0.101) == []
    assert only(watchdog.reset(t + 0.102)).severity == Severity.INFO


def test_after_a_reset_commands_have_the_startup_grace_again_and_are_checked():
    watchdog, t = running(startup_grace=1.0)
    only(watchdog.on_command('left_hip', t, math.nan, True))
    assert only(watchdog.reset(t + 0.01)).severity == Severity.INFO
    for step in range(1, 150):  # controllers take 0.75 s to come back: within the grace
        at = t + 0.01 + step * PERIOD
        for joint in JOINT_NAMES:
            assert watchdog.on_state(joint, at, MID, 5.0e6, 1.0e6, ValveMode.ASSIST) == []
        assert watchdog.check(at) == []
    assert feed(watchdog, t + 0.8) == []
    event = only(watchdog.on_command('left_hip', t + 0.801, math.nan, True))
    assert event.kind == SafetyKind.INVALID_COMMAND


def test_a_reset_without_a_latched_stop_says_so():
    watchdog, t = running()
    event = only(watchdog.reset(t))
    assert (event.kind, event.severity, event.latched) == (SafetyKind.RESET, Severity.INFO, False)
    assert event.text == 'reset: no stop was latched'


def test_diagnostics_give_each_joint_a_level_message_and_values():
    watchdog, t = running()
    watchdog.on_state('left_knee', t, MID, 16.5e6, 0.0, ValveMode.ASSIST)
    levels = {d.joint: d for d in watchdog.diagnostics(t)}
    assert levels['left_knee'].level == LEVEL_WARN
    assert levels['left_knee'].message == 'over-pressure'
    assert levels['left_hip'].level == LEVEL_OK
    assert dict(levels['left_hip'].values)['pressure_a [Pa]'] == '5000000'
    assert dict(levels['left_hip'].values)['latched'] == 'false'
    watchdog.on_command('right_hip', t, math.nan, True)
    levels = {d.joint: d for d in watchdog.diagnostics(t + 0.2)}
    assert levels['right_hip'].level == LEVEL_STALE
    assert levels['right_hip'].message.startswith('no state for 0.2')
    assert 'invalid command; stopped until reset' in levels['right_hip'].message
    feed(watchdog, t + 0.2)
    levels = {d.joint: d for d in watchdog.diagnostics(t + 0.2)}
    assert levels['left_hip'].level == LEVEL_ERROR
    assert levels['left_hip'].message == 'stopped until reset'


def test_a_second_publisher_of_a_joints_command_is_fatal_names_both_and_blocks_a_reset():
    watchdog, t = running()
    topic = '/left_hip/has_command'
    assert watchdog.on_sources('left_hip', topic, ['/pd_controller']) == []
    event = only(watchdog.on_sources('left_hip', topic, ['/pd_controller', '/rogue']))
    assert (event.joint, event.kind, event.severity, event.value, event.limit, event.latched) \
        == ('left_hip', SafetyKind.SECOND_SOURCE, Severity.FATAL, 2.0, 1.0, True)
    assert '/pd_controller' in event.text and '/rogue' in event.text
    assert watchdog.stopped
    # Reported once while it lasts; a reset is refused until the second publisher is gone.
    assert watchdog.on_sources('left_hip', topic, ['/rogue', '/pd_controller']) == []
    refused = only(watchdog.reset(t))
    assert (refused.kind, refused.severity, refused.latched) == (
        SafetyKind.SECOND_SOURCE, Severity.WARN, True)
    assert watchdog.on_sources('left_hip', topic, ['/pd_controller']) == []
    assert only(watchdog.reset(t)).kind == SafetyKind.RESET
    assert not watchdog.stopped


def test_a_second_publisher_that_ros_names_late_is_reported_again_by_its_name():
    watchdog, _ = running()
    topic = '/left_hip/has_state'
    unnamed = 'an unnamed node (publisher gid 0a0b)'
    first = only(watchdog.on_sources('left_hip', topic, ['/left_hip_plant', unnamed]))
    assert unnamed in first.text and watchdog.stopped
    # The stop did not wait for the name; once ROS gives it, the same condition names it.
    named = only(watchdog.on_sources('left_hip', topic, ['/left_hip_plant', '/rogue_plant']))
    assert (named.kind, named.severity, named.latched) == (
        SafetyKind.SECOND_SOURCE, Severity.FATAL, True)
    assert '/rogue_plant' in named.text and '/left_hip_plant' in named.text
    assert watchdog.on_sources('left_hip', topic, ['/rogue_plant', '/left_hip_plant']) == []
    # Gone and back: a new condition, reported anew.
    assert watchdog.on_sources('left_hip', topic, ['/left_hip_plant']) == []
    assert only(watchdog.on_sources('left_hip', topic, ['/left_hip_plant', '/rogue_plant']))


def test_one_publisher_per_topic_on_every_joint_raises_nothing():
    watchdog, _ = running()
    for joint in JOINT_NAMES:
        assert watchdog.on_sources(joint, f'/{joint}/has_state', [f'/{joint}_plant']) == []
        assert watchdog.on_sources(joint, f'/{joint}/has_command', ['/pd_controller']) == []
        assert watchdog.on_sources(joint, f'/{joint}/has_command', []) == []
    assert not watchdog.stopped


class SourceCheck:
    """Stands for the graph: says whether the reference's publisher is present, counting asks."""

    def __init__(self, present=True):
        self.present = present
        self.asked = 0

    def __call__(self):
        """Answer whether the publisher is present."""
        self.asked += 1
        return self.present


def referenced(until=0.1, **options):
    """Return a running watchdog that also had a reference every period up to ``until`` [s]."""
    watchdog, t = running(until, **options)
    for at in np.arange(0.0, until, PERIOD):
        assert watchdog.on_reference(at, dict.fromkeys(JOINT_NAMES, 0.3)) == []
    return watchdog, t - PERIOD


def test_nothing_is_judged_of_a_reference_before_the_first_one():
    watchdog, t = running()
    source = SourceCheck()
    assert watchdog.check_reference(t + 10.0, source) == []
    assert source.asked == 0 and not watchdog.holding


def test_a_lost_reference_latches_one_hold_an_error_not_a_stop():
    watchdog, last = referenced(startup_grace=0.0)  # tracking judged from the start
    source = SourceCheck()
    assert watchdog.check_reference(last + 0.049, source) == []  # within the limit
    assert source.asked == 0  # the graph is asked only once the reference is stale
    event = only(watchdog.check_reference(last + 0.06, source))
    assert (event.joint, event.kind, event.severity, event.latched) == (
        '', SafetyKind.STALE_REFERENCE, Severity.ERROR, True)
    assert (event.value, event.limit) == (pytest.approx(0.06), 0.05)
    assert 'no joint reference for 0.060 s' in event.text
    assert watchdog.holding and not watchdog.stopped
    assert watchdog.check_reference(last + 1.0, source) == []  # once while it lasts
    assert feed(watchdog, last + 1.0) == []  # the robot side itself is sound
    # The reference comes back, far from where the joints hold: no tracking error while held.
    assert tracking_states(watchdog, 'left_knee', last + 1.0, 0.5, -0.6) == []
    assert watchdog.holding and not watchdog.stopped


def test_a_hold_is_released_only_by_a_reset_once_the_reference_is_back():
    watchdog, last = referenced()
    only(watchdog.check_reference(last + 0.1, SourceCheck()))
    refused = only(watchdog.reset(last + 0.2))
    assert (refused.kind, refused.severity, refused.latched) == (
        SafetyKind.STALE_REFERENCE, Severity.WARN, True)
    assert 'reset refused: no joint reference for 0.200 s' in refused.text
    watchdog.on_reference(last + 0.3, dict.fromkeys(JOINT_NAMES, 0.3))
    assert watchdog.check_reference(last + 0.3, SourceCheck()) == []
    assert watchdog.holding  # the reference came back, but motion waits for the reset
    released = only(watchdog.reset(last + 0.31))
    assert (released.kind, released.severity, released.latched) == (
        SafetyKind.RESET, Severity.INFO, False)
    assert released.text.startswith('reset: hold released (latched by stale reference')
    assert not watchdog.holding


def test_a_reference_withdrawn_by_its_publisher_raises_nothing_until_a_new_one_goes_stale():
    watchdog, last = referenced()
    gone = SourceCheck(present=False)
    assert watchdog.check_reference(last + 0.1, gone) == []
    assert watchdog.check_reference(last + 0.2, gone) == []
    assert gone.asked == 1 and not watchdog.holding
    watchdog.on_reference(last + 1.0, dict.fromkeys(JOINT_NAMES, 0.3))
    assert only(watchdog.check_reference(last + 1.1, SourceCheck())).kind \
        == SafetyKind.STALE_REFERENCE


def test_at_the_start_tracking_errors_wait_the_startup_grace_after_the_first_reference():
    watchdog, t = running(startup_grace=1.0)
    # The joint stands far off its first reference (0.5 rad), as a wearer's may.
    assert tracking_states(watchdog, 'left_knee', t, 0.95, 0.5) == []  # within the grace
    event = only(tracking_states(watchdog, 'left_knee', t + 0.95, 0.4, 0.5))
    assert (event.kind, event.severity) == (SafetyKind.TRACKING_ERROR, Severity.FATAL)


def test_after_a_reset_tracking_errors_wait_the_startup_grace_for_the_joints_to_rejoin():
    watchdog, t = running(startup_grace=1.0)
    watchdog.on_reference(t, dict.fromkeys(JOINT_NAMES, 0.3))
    only(watchdog.check_reference(t + 0.1, SourceCheck()))
    watchdog.on_reference(t + 0.1, dict.fromkeys(JOINT_NAMES, 0.3))  # the reference is back
    assert only(watchdog.reset(t + 0.1 + PERIOD)).kind == SafetyKind.RESET
    assert tracking_states(watchdog, 'left_knee', t + 0.1, 0.9, 0.5) == []  # within the grace
    event = only(tracking_states(watchdog, 'left_knee', t + 1.0, 0.4, 0.5))
    assert (event.kind, event.severity) == (SafetyKind.TRACKING_ERROR, Severity.FATAL)

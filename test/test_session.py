"""The whole exoskeleton as separate processes, without launch files: track, record, stop, replay.

One session (four plants, the PD controller, the watchdog, the gait publisher, the recorder)
walks for 8 s and squats for 8 s; the tests then read its bag, replay it, overload a joint and
kill a plant. The tests run in file order and share the session.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from session_observer import bag_so_far, observed_session, outside_stalls, read_so_far

from exo_has_bringup.analysis import tracking
from exo_has_bringup.plan import SessionConfig, recorded_topics
from exo_has_bringup.report import segments_of, write_report
from exo_has_common.bag import bag_topics, read_messages, recover_bag
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    JOINT_REFERENCE_TOPIC,
)
from exo_has_msgs.msg import GaitPhase
from exo_has_runtime.processes import NodeProcess
from exo_has_sim import model
from exo_has_sim.diagnosis.compare import (
    DEFAULT_HORIZON,
    fit_percent,
    horizon_samples,
    make_windows,
)
from exo_has_sim.diagnosis.data import MAX_GAP_PERIODS, Limits, bag_columns, check_columns
from exo_has_sim.diagnosis.diagnose import DEFAULT_BURN_IN
from exo_has_sim.diagnosis.fitting import evaluate
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.loads import JointLoad, squat_moments
from exo_has_sim.parameters import load_parameters

pytestmark = pytest.mark.process  # every test here starts processes

MOTIONS, DURATIONS = ('walk', 'squat'), (8.0, 8.0)
RATE = 200.0
# The searched design (issue 26) walks at the paper's 0.85 strides/s within the pump, under loads
# that follow the gait for the paper's 25 kg: the paper's squat band for the hips, and issue 26's
# walking bounds (ten demos, bench/demo_series.py: hips 0.89 deg at most, knees 3.48).
HIP_SQUAT_BAND = (-1.5, 2.5)  # deg, section 5.3
HIP_WALK_PEAK = 3.0  # deg
KNEE_PEAK = 5.0  # deg
CARRIED_MASS = 25.0  # kg, SessionConfig's default
STOP_BOUND = 0.25  # s: overload to every joint commanded to stop (10 control periods + relief)
STALE_BOUND = 0.5  # s: plants killed to the stale-state event (stale after 200 ms + scheduling)
# What the nominal model reaches on a session's bag, as compare.py's module docstring states it:
# the validated fit [%] at least and any validation window's RMS error at most [m, Pa, rad/s].
# Eight sessions (32 joints) reached 99.0 %, 88.9 % and 97.6 % at least and erred by 0.30 mm,
# 0.33 MPa and 5.2 rad/s at most in a window: here half as much error again, for the ticks'
# jitter of a busy machine.
NOMINAL_FIT = {'position': 98.5, 'pressure_a': 83.0, 'motor_speed': 96.5}
WINDOW_RMS = {'position': 0.45e-3, 'pressure_a': 0.5e6, 'motor_speed': 8.0}


@pytest.fixture(scope='module')
def session(tmp_path_factory):
    config = SessionConfig(MOTIONS, DURATIONS, RATE, loads=True)
    # The tests here read commands and events only: spare the machine the observer's states.
    with observed_session(config, tmp_path_factory.mktemp('session'), states=False) as pair:
        yield pair


@pytest.fixture(scope='module')
def recorded(session):
    running, _observer = session
    return read_so_far(running)


def test_the_hips_track_within_the_papers_squat_band_and_the_knees_within_their_bound(recorded):
    # Judged outside process stalls (a stall of 0.2 s once took a hip's walking peak to
    # 17.9 deg). How often this machine stalls is measured by bench/stalls.py, not timed here
    # (a clean CI run once left out 2.3 s of 16 s); the test needs half the session to judge.
    steady, left_out, stalls = outside_stalls(recorded, RATE)
    assert left_out <= 0.5 * sum(DURATIONS), (left_out, stalls)
    rows = tracking(steady, segments_of(MOTIONS, DURATIONS))
    assert len(rows) == 8
    for row in rows:
        if row.joint.endswith('hip') and row.segment.endswith('squat'):
            assert HIP_SQUAT_BAND[0] <= row.minimum and row.maximum <= HIP_SQUAT_BAND[1], row
        elif row.joint.endswith('hip'):
            assert row.peak <= HIP_WALK_PEAK, row
        else:
            assert row.peak <= KNEE_PEAK, row
        if row.segment.endswith('walk'):
            assert row.saturated < 0.01, row  # the motor keeps up with the walk


def test_each_plants_load_follows_its_normative_moment_at_the_published_phase(recorded):
    gait_table = load_gait_cycle()
    phases = recorded.gait
    walking = phases['motion'] == GaitPhase.MOTION_WALK
    assert np.count_nonzero(walking) >= 0.9 * RATE * DURATIONS[0]
    # What the publisher sends is Winter's moment at the phase it names, right leg half a
    # cycle behind, ramped in and out with the motion: evaluated there, not interpolated (an
    # interpolated moment once missed it by 3.8e-3 N m/kg at a corner of the table).
    hip, knee = gait_table.moments_at(phases['phase'][walking])
    amplitude = phases['amplitude'][walking]
    np.testing.assert_allclose(phases['left_hip'][walking], amplitude * hip, atol=1e-12)
    np.testing.assert_allclose(phases['left_knee'][walking], amplitude * knee, atol=1e-12)
    right_hip, right_knee = gait_table.moments_at(phases['phase'][walking] + 0.5)
    np.testing.assert_allclose(phases['right_hip'][walking], amplitude * right_hip, atol=1e-12)
    np.testing.assert_allclose(phases['right_knee'][walking], amplitude * right_knee,
                               atol=1e-12)
    # Squatting, the quasi-static squat's moments at the posture of the references sent.
    squatting = phases['motion'] == GaitPhase.MOTION_SQUAT
    assert np.count_nonzero(squatting) >= 0.9 * RATE * DURATIONS[1]
    posture = [np.interp(phases['t'][squatting], recorded.reference_t, recorded.reference[:, k])
               for k in range(2)]
    squat_hip, squat_knee = squat_moments(posture[0], posture[1], 1.0)
    np.testing.assert_allclose(phases['left_hip'][squatting], squat_hip, atol=2e-3)
    np.testing.assert_allclose(phases['left_knee'][squatting], squat_knee, atol=2e-3)
    for joint in JOINT_NAMES:
        load = JointLoad(load_parameters(joint_type_of(joint)), CARRIED_MASS)
        states = recorded.states[joint]
        inside = (states['t'] > phases['t'][0] + 0.05) & (states['t'] < phases['t'][-1])
        t, force = states['t'][inside], states['load_force'][inside]
        # Each state's load is the one its plant set from a phase of the last few periods,
        # at the position it then had: between the loads of the phases 30 ms either side.
        window = round(0.03 * RATE)
        expected = load.force(np.interp(t, phases['t'], phases[joint]), states['position'][inside])
        low = np.minimum.reduce([np.roll(expected, k) for k in range(-window, window + 1)])
        high = np.maximum.reduce([np.roll(expected, k) for k in range(-window, window + 1)])
        ok = (force >= low - 1.0) & (force <= high + 1.0)
        assert np.mean(ok[window:-window]) > 0.99, (joint, np.mean(ok))
        # It varies along the gait, from the wearer's push up to the stance's moment.
        walk = (t > recorded.start + 2.0) & (t < recorded.start + DURATIONS[0] - 2.0)
        assert force[walk].min() == pytest.approx(load.push, rel=1e-6)
        assert force[walk].max() > load.push + 40.0, joint


def test_no_fatal_event_is_raised_in_normal_walking_and_squatting(recorded):
    fatal = [e for e in recorded.events if e.severity >= 3]
    assert fatal == []


def test_the_bag_holds_every_topic_at_its_expected_rate(recorded, session, tmp_path):
    running, _observer = session
    # Every topic is declared, even one without messages: a quiet session raises no event.
    recover_bag(running.bag, tmp_path / 'copy')
    declared = {topic.topic for topic in bag_topics(tmp_path / 'copy')}
    expected = set(recorded_topics(with_loads=False))
    assert expected <= declared, expected - declared
    streams = {f'/{JOINT_REFERENCE_TOPIC}': recorded.reference_t}
    streams.update({f'/{joint}/has_state': recorded.states[joint]['t'] for joint in JOINT_NAMES})
    streams.update({f'/{joint}/has_command': recorded.commands[joint]['t']
                    for joint in JOINT_NAMES})
    _steady, left_out, stalls = outside_stalls(recorded, RATE)
    for topic, stamps in streams.items():
        # The rate each node keeps is its median interval: a stall of the machine takes
        # messages away (bench/stalls.py counts them) but leaves the rate a node runs at; a
        # lost or doubled stream is far off either way. Stalls aside, none goes missing.
        assert 1.0 / np.median(np.diff(stamps)) == pytest.approx(RATE, rel=0.02), topic
        assert len(stamps) >= 0.95 * RATE * (sum(DURATIONS) - left_out), (topic, stalls)
    assert recorded.counts['/diagnostics'] >= sum(DURATIONS) * 0.8  # 1 Hz


def test_the_report_is_written_with_its_plots(recorded, tmp_path):
    report = write_report(recorded, tmp_path, MOTIONS, DURATIONS)
    text = report.read_text()
    assert '| left_hip | 2 squat |' in text
    for name in ('joint_angles.png', 'tracking_error.png', 'position.png', 'pressure.png',
                 'load.png', 'motor_speed.png'):
        assert (tmp_path / name).stat().st_size > 10_000, name


def test_the_nominal_model_predicts_every_window_of_each_joint_as_the_sampling_allows(recorded,
                                                                                      session):
    # The plant is the model: each window starts from the state the plant was in (its motor
    # speed the measured one) and the nominal prediction errs by what the bag's sampling
    # leaves, the figure compare.py's module docstring states.
    running, _observer = session
    bag = bag_so_far(running)  # the copy the recorded fixture read, closed
    for joint in JOINT_NAMES:
        plant = _longest_stretch(bag, joint)
        m = plant.measurement
        windows = make_windows(m.samples, horizon_samples(DEFAULT_HORIZON, m.period),
                               plant.first_start, round(DEFAULT_BURN_IN / m.period))
        span = windows.validation_span
        assert span.count >= 8, (joint, m.notes)
        start = plant.initial_states(plant.params, 0.0, np.zeros(span.count), span.starts)
        assert_allclose(start[:, model.N], m.optional['motor_speed'][span.starts], rtol=1e-12,
                        err_msg=joint)
        nominal = evaluate(plant, [plant.nominal()], span, np.ones(len(plant.outputs)))[0]
        error = nominal.measured - nominal.predicted
        for k, output in enumerate(plant.outputs):
            fit = fit_percent(nominal.measured[..., k], nominal.predicted[..., k])
            assert fit >= NOMINAL_FIT[output], (joint, output, fit, m.notes)
            worst = float(np.max(np.sqrt(np.mean(error[..., k] ** 2, axis=1))))
            assert worst <= WINDOW_RMS[output], (joint, output, worst, m.notes)


def _longest_stretch(bag: Path, joint: str) -> HasPlant:
    """Return the diagnosis' plant of a joint's longest stretch of the bag without a stall.

    A stall of the machine (bench/README.md, "Stalls") leaves a gap that the diagnosis refuses
    to bridge; the stretch either side of it is a record of its own.
    """
    columns, source = bag_columns(bag, joint)
    steps = np.diff(columns['time'])
    breaks = np.flatnonzero(steps > MAX_GAP_PERIODS * np.median(steps)) + 1
    edges = np.concatenate(([0], breaks, [len(steps) + 1]))
    first = int(np.argmax(np.diff(edges)))
    part = {name: values[edges[first]:edges[first + 1]] for name, values in columns.items()}
    params = load_parameters(joint_type_of(joint))
    return HasPlant(check_columns(part, 'has', source,
                                  Limits(params.stroke, params.motor_speed_max)), params)


def test_replaying_the_bag_reproduces_its_messages(session, tmp_path):
    running, _observer = session
    source = tmp_path / 'source'
    recover_bag(running.bag, source)
    topic = '/joint_reference'
    with read_messages(source, [topic]) as messages:
        original = [m.data for m in messages][:400]  # 2 s of references
    assert len(original) == 400
    trimmed = tmp_path / 'trimmed'
    _write_bag(trimmed, topic, original)
    copy = tmp_path / 'copy'
    with NodeProcess('exo_has_runtime.recorder', [
            '--ros-args', '-r', '__node:=replay_recorder', '-p', f'output:={copy}',
            '-p', f"topics:=['{topic}_replayed']"]) as recorder:
        with NodeProcess('exo_has_runtime.replay', [
                str(trimmed), '--rate', '1', '--wait-for-subscribers',
                '--ros-args', '-r', f'{topic}:={topic}_replayed']) as replay:
            assert replay.wait(timeout_s=30) == 0, replay.output
        time.sleep(0.3)
        recorder.stop()
    with read_messages(copy) as messages:
        replayed = [m.data for m in messages]
    assert replayed == original


def _write_bag(path: Path, topic: str, payloads: list[bytes]) -> None:
    from exo_has_common.bag import BagWriter

    with BagWriter(path) as bag:
        bag.add_topic(topic, 'sensor_msgs/msg/JointState', [])
        for index, data in enumerate(payloads):
            bag.write(topic, 1_000_000_000 + index * 5_000_000, data)


def test_an_overload_opens_the_safety_valve_and_stops_every_joint_within_the_bound(session):
    _running, observer = session
    load = observer.float64(data=4000.0)  # N: 26 MPa on the 14 mm bore, over the 18 MPa relief
    start = time.monotonic()
    observer.loads['left_knee'].publish(load)

    def valve_event():
        for t, event in observer.events:
            if t >= start and event.kind == 1 and event.severity == 3:
                return t
        return None

    def all_stopped():
        times = []
        for joint in JOINT_NAMES:
            stops = [t for t, _speed, enable in observer.commands[joint]
                     if t >= start and not enable]
            if not stops:
                return None
            times.append(stops[0])
        return max(times)

    opened = observer.wait_for(valve_event, 5.0)
    stopped = observer.wait_for(all_stopped, 5.0)
    assert opened - start < STOP_BOUND
    assert stopped - start < STOP_BOUND, f'stopped after {stopped - start:.3f} s'
    # Latched: the joints stay stopped until a reset.
    time.sleep(0.3)
    with observer.lock:
        late = [c for j in JOINT_NAMES for c in observer.commands[j][-20:]]
    assert all(not enable and speed == 0.0 for _t, speed, enable in late)
    observer.loads['left_knee'].publish(observer.float64(data=1000.0))
    time.sleep(0.2)
    observer.reset.publish(observer.empty())
    observer.wait_for(lambda: next((t for t, e in observer.events
                                    if t > start and e.kind == 13), None), 5.0)


def test_a_killed_plant_is_detected_as_stale(session):
    running, observer = session
    # Timed on the watchdog's clock (the event's stamp, system time): the observer in this
    # process may take the event later than the watchdog raised it.
    start = time.time()
    # The plants share a process (session.COMPOSITION): killing it kills all four.
    running.process_of('right_hip_plant').kill()

    def stale():
        for _t, event in observer.events:
            stamp = event.header.stamp.sec + event.header.stamp.nanosec * 1e-9
            if stamp >= start and event.kind == 5 and event.joint == 'right_hip':
                return stamp
        return None

    detected = observer.wait_for(stale, 5.0)
    assert detected - start < STALE_BOUND

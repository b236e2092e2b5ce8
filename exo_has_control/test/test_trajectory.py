import math

import numpy as np
import pytest

from exo_has_control.trajectory import (
    ReferenceTable,
    Schedule,
    TrialPlan,
    envelope,
    joint_angles,
    joint_velocities,
)
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import squat_moments
from exo_has_sim.parameters import load_parameters

GAIT = load_gait_cycle()


def test_walking_follows_the_normative_cycle_with_the_right_leg_half_a_cycle_behind():
    plan = TrialPlan('walk', duration=20.0, ramp=2.0)
    t = np.linspace(5.0, 15.0, 2001)
    angles = joint_angles(plan, GAIT, t)
    left_hip, left_knee = GAIT.angles_at(t * 0.85)
    right_hip, _ = GAIT.angles_at(t * 0.85 + 0.5)
    np.testing.assert_allclose(angles[:, 0], left_hip, atol=1e-12)
    np.testing.assert_allclose(angles[:, 1], left_knee, atol=1e-12)
    np.testing.assert_allclose(angles[:, 2], right_hip, atol=1e-12)
    stride = round(1 / 0.85 / (t[1] - t[0]))
    assert np.max(np.abs(angles[stride:, 0] - angles[:-stride, 0])) < 0.01  # periodic


@pytest.mark.parametrize('motion', ['walk', 'squat'])
def test_trials_start_and_end_standing_without_jumps(motion):
    plan = TrialPlan(motion, duration=8.0, ramp=1.5)
    t = np.linspace(0.0, 8.0, 8001)
    angles = joint_angles(plan, GAIT, t)
    velocities = joint_velocities(plan, GAIT, t)
    np.testing.assert_allclose(angles[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(angles[-1], 0.0, atol=1e-12)
    assert np.max(np.abs(velocities[[0, -1]])) < 1e-3
    assert np.max(np.abs(np.diff(angles, axis=0))) < 0.01  # continuous at 1 ms
    # Knee swing accelerates at about 200 rad/s^2; a kink in the references would jump ~3000.
    assert np.max(np.abs(np.diff(velocities, axis=0))) < 0.4  # rad/s per ms


def test_squats_reach_the_planned_depth_at_half_a_hertz_inside_the_linkage_range():
    plan = TrialPlan('squat', duration=10.0, ramp=0.5)
    t = np.linspace(0.0, 10.0, 10001)
    angles = joint_angles(plan, GAIT, t)
    assert angles[1000, 0] == pytest.approx(math.radians(40.0), abs=1e-9)  # bottom at 1 s
    assert angles[3000, 1] == pytest.approx(math.radians(70.0), abs=1e-9)
    assert angles[4000, 0] == pytest.approx(0.0, abs=1e-9)  # top again at 4 s
    Linkage.from_parameters(load_parameters('hip')).position(angles[:, 0])
    Linkage.from_parameters(load_parameters('knee')).position(angles[:, 1])


def test_the_envelope_is_zero_outside_and_one_inside():
    plan = TrialPlan('walk', duration=10.0, ramp=1.0)
    values = envelope(plan, np.array([-1.0, 0.0, 0.5, 1.0, 5.0, 9.0, 10.0, 11.0]))
    np.testing.assert_allclose(values, [0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 0.0, 0.0])


@pytest.mark.parametrize(('kwargs', 'message'), [
    ({'motion': 'jump', 'duration': 5.0}, "unknown motion 'jump'"),
    ({'motion': 'walk', 'duration': -1.0}, 'duration must be positive'),
    ({'motion': 'walk', 'duration': 5.0, 'stride_frequency': math.nan}, 'stride_frequency'),
    ({'motion': 'walk', 'duration': 5.0, 'ramp': 3.0}, 'ramp must lie within'),
])
def test_bad_plans_are_refused_naming_the_problem(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrialPlan(**kwargs)


def test_the_moments_are_the_tables_at_each_legs_phase_and_the_squats_at_its_posture():
    walk, squat = TrialPlan('walk', duration=6.0, ramp=1.0), TrialPlan('squat', duration=4.0)
    schedule = Schedule((walk, squat))
    t = np.linspace(0.0, 10.0, 4001)
    moments = schedule.moments(GAIT, t)
    walking = t < 6.0
    weight = envelope(walk, t[walking])
    left_hip, left_knee = GAIT.moments_at(t[walking] * 0.85)
    right_hip, right_knee = GAIT.moments_at(t[walking] * 0.85 + 0.5)
    np.testing.assert_allclose(moments[walking], weight[:, None] * np.column_stack(
        [left_hip, left_knee, right_hip, right_knee]), atol=1e-12)
    angles, _ = schedule.references(GAIT, t[~walking])
    hip, knee = squat_moments(angles[:, 0], angles[:, 1], 1.0)
    np.testing.assert_allclose(moments[~walking][:, :2], np.column_stack([hip, knee]), atol=1e-12)
    assert moments[~walking].max() > 1.0  # N m/kg: 70 deg of knee under the load
    # The phase each sample names, with the envelope; standing after the trials.
    assert schedule.phase_at(2.0 / 0.85 + 0.1) == pytest.approx(
        ('walk', 0.085, 1.0), abs=1e-9)
    motion, phase, amplitude = schedule.phase_at(6.0 + 1.5)
    assert (motion, amplitude) == ('squat', pytest.approx(1.0)) and phase == pytest.approx(0.75)
    assert schedule.phase_at(10.5) == ('stand', 0.0, 0.0)


def test_each_sample_of_the_table_names_the_moments_at_its_own_phase_and_posture():
    walk, squat = TrialPlan('walk', duration=6.0, ramp=1.0), TrialPlan('squat', duration=4.0)
    schedule = Schedule((walk, squat))
    table = ReferenceTable(schedule, GAIT)
    # Between the grid's points too: an interpolated moment missed the one at the phase by
    # up to 3.4e-3 N m/kg at the gait table's corners.
    times = np.sort(np.random.default_rng(7).uniform(0.0, 11.0, 4000))
    for time in times:
        sample = table.sample(time)
        assert (sample.motion, sample.phase, sample.amplitude) == schedule.phase_at(time)
        angles, _ = schedule.references(GAIT, [time])
        np.testing.assert_allclose(sample.angles, angles[0], atol=1e-4)
        if sample.motion == 'walk':
            hip, knee = GAIT.moments_at(sample.phase)
            right_hip, right_knee = GAIT.moments_at(sample.phase + 0.5)
            expected = sample.amplitude * np.array([hip, knee, right_hip, right_knee])
        elif sample.motion == 'squat':
            hip, knee = squat_moments(sample.angles[0], sample.angles[1], 1.0)
            expected = np.array([hip, knee, hip, knee])
        else:
            expected = np.zeros(4)
        np.testing.assert_allclose(sample.moments, expected, rtol=0.0, atol=1e-12)

"""A joint's reference as cylinder targets: holding, and rejoining after a stop or a hold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from exo_has_control.tracking import DEFAULT_REJOIN_SPEED, ReferenceFollower
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters

KNEE = load_parameters('knee')
LINKAGE = Linkage.from_parameters(KNEE)
PERIOD = 0.005  # s
TIMEOUT = 0.1  # s


def follower(rejoin_speed=DEFAULT_REJOIN_SPEED):
    return ReferenceFollower('left_knee', KNEE, TIMEOUT, rejoin_speed)


def take(follower_, t, angle, rate=0.0):
    assert follower_.take(t, ['left_knee'], [angle], [rate]) is None


def test_a_reference_is_followed_at_once_and_held_still_once_it_is_old():
    f = follower()
    x0 = LINKAGE.position_at(1.0)
    take(f, 0.0, 1.0, 0.5)
    assert f.target(0.0, x0)[0] == pytest.approx(x0)  # started where the reference is
    assert not f.rejoining
    take(f, 0.0, 1.0, 0.5)
    x, v = f.target(0.05, 0.03)
    assert x == pytest.approx(LINKAGE.position_at(1.0))
    assert v == pytest.approx(LINKAGE.velocity_at(1.0, 0.5))
    assert f.target(0.2, 0.03) == (pytest.approx(x), 0.0)  # older than the timeout


def test_after_a_rejoin_the_target_ramps_to_a_distant_reference_at_the_rejoin_speed():
    f = follower(rejoin_speed=0.05)
    stand = LINKAGE.position_at(0.1)  # where the joint stands when control resumes
    f.rejoin(stand)
    assert f.target(0.0, stand) == (stand, 0.0)  # held until a reference comes
    far = LINKAGE.position_at(1.2)
    assert abs(far - stand) > 0.5 * KNEE.stroke  # flexion shortens the cylinder
    targets = []
    for t in np.arange(0.0, 2.0, PERIOD):
        take(f, t, 1.2)
        targets.append(f.target(t, stand))
    positions = np.array([x for x, _ in targets])
    steps = np.abs(np.diff(positions))
    assert steps.max() <= 0.05 * PERIOD * (1 + 1e-9)  # never faster than the rejoin speed
    assert positions[-1] == pytest.approx(far)  # and it caught up
    caught = int(np.argmax(np.isclose(positions, far)))
    assert caught * PERIOD == pytest.approx(abs(far - stand) / 0.05, abs=2 * PERIOD)
    assert not f.rejoining
    assert targets[1][1] == pytest.approx(0.05 * np.sign(far - stand))  # the ramp's speed


@pytest.mark.parametrize('rated', [True, False], ids=['with its rate', 'without rates'])
def test_a_reference_sweeping_past_the_ramp_is_joined_where_it_crosses(rated):
    f = follower(rejoin_speed=0.05)
    stand = LINKAGE.position_at(1.0)
    f.rejoin(stand)
    # The reference starts beyond the ramp and sweeps back through it at about 0.2 m/s, four
    # times the rejoin speed; from 0.42 rad it passes the ramp between two periods, never
    # coming within a step of it.
    rate = -0.2 / LINKAGE.velocity_at(0.42, 1.0)  # rad/s
    side = LINKAGE.position_at(0.42) - stand
    ramp, crossed = stand, None
    for k in range(200):
        t = k * PERIOD
        angle = 0.42 + rate * t
        take(f, t, angle, rate if rated else 0.0)
        if crossed is None and (LINKAGE.position_at(angle) - ramp) * side < 0.0:
            crossed = t  # the reference is past where the ramp stood a period ago
        x, v = f.target(t, stand)
        if not f.rejoining:
            break
        ramp = x
        assert v == pytest.approx(math.copysign(0.05, side))
    assert crossed is not None and not f.rejoining
    assert t == crossed  # joined in the period it crossed, not chased on
    assert (x, v) == (pytest.approx(LINKAGE.position_at(angle)),
                      pytest.approx(LINKAGE.velocity_at(angle, rate if rated else 0.0)))


@pytest.mark.parametrize('rate', [0.0, 1.0], ids=['still', 'with a rate of 1 rad/s'])
def test_a_reference_that_jumps_across_the_ramp_is_still_ramped_to(rate):
    f = follower(rejoin_speed=0.05)
    stand = LINKAGE.position_at(0.5)
    f.rejoin(stand)
    take(f, 0.0, 0.3, rate)  # on one side of the ramp
    f.target(0.0, stand)
    take(f, PERIOD, 1.2, rate)  # then far on the other, in one message
    x, v = f.target(PERIOD, stand)
    assert f.rejoining
    assert abs(x - stand) <= 0.05 * PERIOD * (1 + 1e-9)
    assert v == pytest.approx(math.copysign(0.05, LINKAGE.position_at(1.2) - stand))


def test_after_a_hold_in_walking_every_joint_rejoins_within_a_stride_from_any_phase():
    from exo_has_common.joints import JOINT_NAMES
    from exo_has_control.trajectory import Schedule, TrialPlan
    from exo_has_sim.gait import WINTER, load_gait_cycle

    gait = load_gait_cycle(WINTER)
    t = np.arange(0.0, 12.0, PERIOD)
    angles, rates = (np.asarray(a) for a in Schedule((TrialPlan('walk', 12.0),))
                     .references(gait, t))
    stride = 1.0 / TrialPlan('walk', 12.0).stride_frequency  # s
    rng = np.random.default_rng(12)
    for index, joint in enumerate(JOINT_NAMES[:2]):  # left hip and knee: both sides alike
        params = load_parameters('hip' if joint.endswith('hip') else 'knee')
        linkage = Linkage.from_parameters(params)
        worst = 0.0
        for _ in range(60):
            # Held where the joint stood 2-5 s before control resumes at a random phase.
            resume, held = int(rng.uniform(5.0, 7.0) / PERIOD), int(rng.uniform(2.0, 5.0) / PERIOD)
            f = ReferenceFollower(joint, params, TIMEOUT)
            f.rejoin(linkage.position_at(angles[resume - held, index]))
            for i in range(resume, len(t)):
                f.take(t[i], [joint], [angles[i, index]], [rates[i, index]])
                f.target(t[i], 0.0)
                if not f.rejoining:
                    break
            assert not f.rejoining, joint
            worst = max(worst, t[i] - t[resume])
        assert worst < stride, (joint, worst)


@pytest.mark.parametrize('how', ['at the start', 'on a rejoin with nothing measured'])
def test_the_first_reference_is_joined_from_the_first_measured_position_at_the_rejoin_speed(how):
    f = follower(rejoin_speed=0.05)
    if how != 'at the start':
        take(f, 0.0, 1.0)  # a reference before the stop, forgotten by the rejoin
        f.rejoin(None)
    sunk = LINKAGE.position_at(0.2)  # m: where the joint stands when control starts
    assert f.target(0.0, sunk) == (sunk, 0.0)  # held before any reference
    stand = LINKAGE.position_at(0.0)
    positions = []
    for t in np.arange(PERIOD, 1.0, PERIOD):
        take(f, t, 0.0)
        positions.append(f.target(t, sunk)[0])
    steps = np.abs(np.diff([sunk, *positions]))
    assert steps.max() <= 0.05 * PERIOD * (1 + 1e-9)  # no jump to the reference
    caught = int(np.argmax(np.isclose(positions, stand)))
    assert caught * PERIOD == pytest.approx((stand - sunk) / 0.05, abs=2 * PERIOD)
    assert not f.rejoining


def test_a_rejoin_speed_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match='rejoin speed'):
        follower(rejoin_speed=0.0)
    with pytest.raises(ValueError, match='rejoin speed'):
        follower(rejoin_speed=math.nan)

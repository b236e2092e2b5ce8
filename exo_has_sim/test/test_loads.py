"""Loads along the motion (issue 26): the wearer's push, and a walk that stays physical."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim import linear, model
from exo_has_sim.errors import ParameterError
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import (
    TRACKING_LOAD_MASS,
    JointLoad,
    default_load_force,
    wearer_push,
)
from exo_has_sim.parameters import load_parameters
from exo_has_sim.simulate import simulate_closed_loop

PERIOD = 0.005  # s, the paper's 200 Hz
STRIDE_FREQUENCY = 0.85  # Hz, the paper's
ATMOSPHERE = 101325.0  # Pa


def test_a_joint_load_is_the_moment_over_the_lever_arm_or_the_wearers_push():
    knee = load_parameters('knee')
    linkage = Linkage.from_parameters(knee)
    load = JointLoad(knee, 25.0)
    angle = math.radians(20.0)
    position = float(linkage.position(angle))
    lever = float(linkage.lever_arm(angle))
    assert load.force(1.0, position) == pytest.approx(25.0 / lever)
    # A flexor moment, or one too small to push the piston after the pump: the wearer's push.
    assert load.force(-1.0, position) == load.push
    assert load.force(0.0, position) == load.push
    assert load.push == pytest.approx(
        knee.damping * knee.pump_displacement * knee.motor_speed_max / knee.area_a)
    # Beyond the stroke (the end stops give) the lever arm is the end's.
    assert load.force(1.0, knee.stroke + 1e-3) == load.force(1.0, knee.stroke)
    with pytest.raises(ParameterError, match='load mass'):
        JointLoad(knee, math.nan)


def test_the_wearers_push_retracts_the_cylinder_at_the_pumps_top_speed():
    hip = load_parameters('hip')
    push = wearer_push(hip)
    samples = round(0.15 / PERIOD)
    y0 = model.initial_state(hip, hip.stroke - 1e-3, push)
    # Full speed in: the command saturates at the motor's limit at once.
    x_ref = np.zeros((samples, 1))
    run = simulate_closed_loop([hip], y0[None], x_ref, np.zeros_like(x_ref),
                               np.full(samples, push), np.array([[1e6, 0.0, 0.0]]), PERIOD)
    states = run.states[:, 0]
    assert run.commands[-1, 0] == pytest.approx(-hip.motor_speed_max)
    speed = hip.pump_displacement * hip.motor_speed_max / hip.area_a
    assert states[-1, model.V] == pytest.approx(-speed, rel=0.02)
    # While the load comes up to speed the pump outruns the piston: the chamber holds at its
    # vapour pressure (cavitates), never below a vacuum.
    assert states[:, model.PA].min() >= -ATMOSPHERE
    assert states[:, model.VOID].max() > 0.0


@pytest.mark.parametrize('joint', ['hip', 'knee'])
def test_a_walk_under_its_normative_moments_stays_physical_and_tracks_with_the_push(joint):
    params = load_parameters(joint)
    linkage = Linkage.from_parameters(params)
    gait = load_gait_cycle()
    t = np.arange(round(4.0 / PERIOD)) * PERIOD
    phase = STRIDE_FREQUENCY * t
    hip_angle, knee_angle = gait.angles_at(phase)
    hip_moment, knee_moment = gait.moments_at(phase)
    angle = hip_angle if joint == 'hip' else knee_angle
    moment = TRACKING_LOAD_MASS * (hip_moment if joint == 'hip' else knee_moment)
    x_ref = np.asarray(linkage.position(angle), dtype=float)
    v_ref = np.gradient(x_ref, PERIOD)
    gains = np.array([[35e3, 0.0, 1.0 / linear.velocity_gain(params)]])
    signed = moment / linkage.lever_arm(angle)
    pushed = JointLoad(params, TRACKING_LOAD_MASS).force(moment / TRACKING_LOAD_MASS, x_ref)
    runs = {}
    for name, load in (('signed', signed), ('pushed', pushed)):
        y0 = model.initial_state(params, float(x_ref[0]), float(max(load[0], 1.0)))
        runs[name] = simulate_closed_loop([params], y0[None], x_ref[:, None], v_ref[:, None],
                                          load[:, None], gains, PERIOD)
    settled = t >= 1.0
    # The moments alone pull the rod out in swing: the rodless chamber cavitates at vacuum,
    # never below it, and the damping holds the piston under the largest pull's terminal
    # speed beyond what the pump draws (no free fall), but the joint cannot follow.
    states = runs['signed'].states[1:, 0]
    assert states[:, model.PA].min() >= -ATMOSPHERE
    assert states[:, model.VOID].max() > 0.0
    pump = params.pump_displacement * params.motor_speed_max / params.area_a
    assert np.abs(states[:, model.V]).max() <= pump + max(-signed.min(), 0.0) / params.damping
    error = np.degrees(np.abs(linkage.angle(np.clip(states[:, model.X], 0.0, params.stroke))
                              - angle))
    assert error[settled].max() > 20.0
    # With the wearer's push the chamber keeps its oil, the motor keeps up and the joint
    # tracks within issue 26's walking bounds.
    states = runs['pushed'].states[1:, 0]
    assert states[:, model.VOID].max() == 0.0 and states[:, model.PA].min() > 0.0
    error = np.degrees(np.abs(linkage.angle(states[:, model.X]) - angle))
    assert error[settled].max() < (3.0 if joint == 'hip' else 5.0)
    saturated = np.abs(runs['pushed'].commands[:, 0]) >= params.motor_speed_max * (1 - 1e-6)
    assert np.mean(saturated[settled]) < 0.01


def test_the_constant_design_load_is_the_peak_extensor_moment_at_the_standing_lever():
    hip = load_parameters('hip')
    gait = load_gait_cycle()
    lever = float(Linkage.from_parameters(hip).lever_arm(0.0))
    assert_allclose(default_load_force(hip, gait, 50.0), 50.0 * max(gait.hip_moment) / lever)

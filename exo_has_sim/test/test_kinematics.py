import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim.design_search import motions
from exo_has_sim.errors import KinematicsError
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters


@pytest.fixture(params=['hip', 'knee'])
def linkage(request):
    return Linkage.from_parameters(load_parameters(request.param))


def test_the_length_is_the_law_of_cosines_with_the_papers_angles(linkage):
    theta = 0.3
    psi = theta + linkage.angle_offset + math.atan(linkage.ac / linkage.co) \
        + math.atan(linkage.bd / linkage.od)
    r1, r2 = math.hypot(linkage.ac, linkage.co), math.hypot(linkage.bd, linkage.od)
    included = math.pi - psi  # the angle a-O-b
    expected = math.sqrt(r1 ** 2 + r2 ** 2 - 2 * r1 * r2 * math.cos(included))
    assert_allclose(linkage.cylinder_length(theta), expected, rtol=1e-12)


def test_angle_and_position_are_inverse_over_the_range(linkage):
    low, high = linkage.angle_range()
    angles = np.linspace(low, high, 50)
    assert_allclose(linkage.angle(linkage.position(angles)), angles, atol=1e-10)
    assert linkage.position(high) == pytest.approx(0.0, abs=1e-12)
    assert linkage.position(low) == pytest.approx(linkage.stroke, abs=1e-12)


def test_the_jacobian_is_the_derivative_and_does_virtual_work(linkage):
    low, high = linkage.angle_range()
    theta, step = 0.5 * (low + high), 1e-6
    numeric = (linkage.cylinder_length(theta + step) - linkage.cylinder_length(theta - step)) \
        / (2 * step)
    assert_allclose(-linkage.lever_arm(theta), numeric, rtol=1e-7)
    assert_allclose(linkage.velocity(theta, 2.0), 2.0 * numeric, rtol=1e-7)
    force = 1000.0
    torque = linkage.joint_torque(force, theta)
    # Virtual work: F v = tau omega, with tau = -F lever and v = -lever omega.
    assert_allclose(force * linkage.velocity(theta, 1.0), torque * 1.0, rtol=1e-12)
    assert_allclose(linkage.cylinder_force(torque, theta), force, rtol=1e-12)
    assert torque < 0  # pushing extends the joint


@pytest.mark.parametrize('joint', ['hip', 'knee'])
def test_the_walking_and_squatting_ranges_lie_inside_each_joints_stroke(joint):
    linkage = Linkage.from_parameters(load_parameters(joint))
    for task in motions(joint):
        x = linkage.position(task.angle)  # raises outside the stroke
        assert 0.0 < np.min(x) and np.max(x) < linkage.stroke


def test_angles_beyond_the_stroke_are_refused(linkage):
    _low, high = linkage.angle_range()
    with pytest.raises(KinematicsError, match='outside the linkage range'):
        linkage.position(high + 0.2)
    with pytest.raises(KinematicsError):
        linkage.angle(10.0)


def test_the_scalar_forms_agree_with_the_array_forms(linkage):
    low, high = linkage.angle_range()
    for angle in np.linspace(low, high, 25):
        x = float(linkage.position(angle))
        assert_allclose(linkage.position_at(angle), x, rtol=0, atol=1e-12)
        assert_allclose(linkage.angle_at(x), float(linkage.angle(x)), rtol=0, atol=1e-12)
        assert_allclose(linkage.velocity_at(angle, 0.7), float(linkage.velocity(angle, 0.7)),
                        rtol=1e-12)


def test_the_scalar_angle_refuses_an_unreachable_or_nan_extension(linkage):
    with pytest.raises(KinematicsError, match='outside what the linkage can reach'):
        linkage.angle_at(10.0)
    with pytest.raises(KinematicsError):
        linkage.angle_at(math.nan)

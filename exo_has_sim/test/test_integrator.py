"""The compiled integrator's methods: their orders, and their accuracy on HAS runs."""

import math

import numpy as np
import pytest
from test_model import every_valve_mode

from exo_has_sim import integrator, model
from exo_has_sim.diagnosis.has_plant import HAS_ATOL, HAS_RTOL
from exo_has_sim.parameters import load_parameters
from exo_has_sim.reference_solution import simulate_reference
from exo_has_sim.simulate import integrate_packed

HIP = load_parameters('hip')
LOAD = 50.0 * 9.81


def van_der_pol(y):
    return np.array([y[1], (1.0 - y[0] ** 2) * y[1] - y[0]])


def van_der_pol_jacobian(y):
    return np.array([[0.0, 1.0], [-2.0 * y[0] * y[1] - 1.0, 1.0 - y[0] ** 2]])


def fixed_steps(method, steps, matrix, embedded=False):
    """Integrate van der Pol over 1 s in fixed steps, with ``matrix(y)`` for the Jacobian.

    ``embedded``: step on with the embedded solution (whose difference to the step is the
    error estimate) instead of the method's.
    """
    gamma, a, c, m, e = method[:5]
    weights = m - e if embedded else m
    y, h = np.array([2.0, 0.0]), 1.0 / steps
    for _ in range(steps):
        factors = np.eye(2) - gamma * h * matrix(y)
        u = np.zeros((len(m), 2))
        for i in range(len(m)):
            u[i] = np.linalg.solve(factors, gamma * h * van_der_pol(y + a[i, :i] @ u[:i])
                                   + c[i, :i] @ u[:i])
        y = y + weights @ u
    return y


def observed_order(method, matrix, embedded=False):
    exact = fixed_steps(method, 4096, van_der_pol_jacobian)
    coarse, fine = (np.abs(fixed_steps(method, n, matrix, embedded) - exact).max()
                    for n in (40, 80))
    return math.log2(coarse / fine)


@pytest.mark.parametrize(('method', 'order'), [(integrator.ROS34PW2, 3), (integrator.ROS2, 2)],
                         ids=['ROS34PW2', 'ROS2'])
def test_each_method_keeps_its_order_with_a_matrix_other_than_the_jacobian(method, order):
    # Both are W-methods: the order holds whatever matrix stands for the Jacobian, which is
    # what lets a step reuse the factors of an earlier one.
    assert observed_order(method, van_der_pol_jacobian) == pytest.approx(order, abs=0.15)
    skewed = np.array([[0.3, -0.2], [0.5, 0.1]])
    assert observed_order(method, lambda y: van_der_pol_jacobian(y) + skewed) \
        == pytest.approx(order, abs=0.15)
    assert observed_order(method, lambda y: np.zeros((2, 2))) == pytest.approx(order, abs=0.15)


@pytest.mark.parametrize(('method', 'order'), [(integrator.ROS34PW2, 2), (integrator.ROS2, 1)],
                         ids=['ROS34PW2', 'ROS2'])
def test_each_error_estimate_comes_from_a_solution_one_order_lower(method, order):
    # The step size control's exponents (1 / (order + 1)) rest on this.
    assert observed_order(method, van_der_pol_jacobian, embedded=True) \
        == pytest.approx(order, abs=0.15)


def speed_loop_error(max_step):
    """Error of the motor speed after a step command in fixed steps of about max_step."""
    zeta, tau = 0.6, HIP.motor_time_constant
    second = HIP.replace(motor_damping_ratio=zeta)
    period, samples, target = 0.004, 5, 100.0
    y0 = model.initial_state(second, 0.065, LOAD)
    y0[model.N] = 0.0
    out = np.empty((samples + 1, 1, model.N_STATE))
    # Tolerances no step can miss: every step is max_step long.
    integrator.open_loop(y0[None, :], model.pack(second)[None, :], np.full((samples, 1), target),
                         np.full((samples, 1), LOAD), period, np.zeros(1),
                         np.full(model.N_DYNAMIC, 1e30), 0.5, max_step, out)
    t = samples * period
    omega = 2.0 * zeta / tau
    damped = omega * math.sqrt(1.0 - zeta ** 2)
    exact = target * (1.0 - math.exp(-zeta * omega * t) * (
        math.cos(damped * t) + zeta / math.sqrt(1.0 - zeta ** 2) * math.sin(damped * t)))
    return abs(out[-1, 0, model.N] - exact)


def test_the_open_loop_converges_at_third_order_on_the_speed_loop():
    coarse, fine = speed_loop_error(1e-3), speed_loop_error(0.5e-3)
    assert math.log2(coarse / fine) == pytest.approx(3.0, abs=0.3)


def test_at_the_diagnosis_tolerances_the_open_loop_follows_radau_through_every_valve_mode():
    params, commands, loads, y0 = every_valve_mode()
    period = 0.005
    fast = integrate_packed(model.pack(params)[None, :], np.zeros(1), y0[None, :],
                            commands[:, None], loads[:, None], period, rtol=HAS_RTOL,
                            atol=HAS_ATOL)[:, 0]
    reference = simulate_reference(params, y0, commands, loads, period, rtol=1e-10)
    # Where it runs into the end stop (at 15 ms) and cavitates, ROS2 at these tolerances was
    # 45 um and 340 kPa off; ROS34PW2 is 24 um and 130 kPa off.
    assert np.abs(fast[:, model.X] - reference[:, model.X]).max() < 30e-6
    assert np.abs(fast[:, model.PA] - reference[:, model.PA]).max() < 200e3


def test_a_cylinder_thrown_into_its_end_stop_rebounds_as_radau_has_it():
    # In free mode, with no pressure to brake it, a load throws the cylinder into its stop:
    # the stop's damping force sets in at once, a jump the error estimate alone can miss.
    params = HIP
    period = 0.005
    y0 = model.initial_state(params, 0.5 * params.stroke, 0.0, assist=False)
    loads = np.full(120, -3000.0)  # pulling it out
    commands = np.zeros(120)
    fast = integrate_packed(model.pack(params)[None, :], np.zeros(1), y0[None, :],
                            commands[:, None], loads[:, None], period, rtol=HAS_RTOL,
                            atol=HAS_ATOL)[:, 0]
    reference = simulate_reference(params, y0, commands, loads, period, rtol=1e-10)
    assert reference[:, model.X].max() > params.stroke  # it went into the stop
    # 1 um off; 4 um without the check of regimes (integrator._regime), 11 um with ROS2.
    assert np.abs(fast[:, model.X] - reference[:, model.X]).max() < 3e-6

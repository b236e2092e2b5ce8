"""The judgement of a gain change against the nonlinear model the linear one comes from."""

import dataclasses

import numpy as np
import pytest

from exo_has_control.pd import STABILITY_DAMPING_MIN, PdGains, loop_damping, unsafe_gains
from exo_has_sim import model
from exo_has_sim.parameters import load_parameters
from exo_has_sim.simulate import simulate_closed_loop

HIP = load_parameters('hip')
PAPER = PdGains.paper(HIP)
LOAD = 500.0  # N, a push the circuit holds


def step_response(gains, period, seconds=1.5, step=0.002):
    """Cylinder positions [m] after a 2 mm step of the reference, one period of loop delay."""
    params = HIP.with_effects(transport_delay=period)
    x0 = HIP.stroke / 2.0
    samples = round(seconds / period)
    y0 = model.initial_state(params, x0, LOAD)[None, :]
    x_ref = np.full((samples, 1), x0 + step)
    result = simulate_closed_loop([params], y0, x_ref, np.zeros_like(x_ref),
                                  np.full_like(x_ref, LOAD), [gains.kp, gains.kd, 0.0], period)
    return result.states[:, 0, model.X] - (x0 + step)


@pytest.mark.parametrize('period', [0.005, 0.001])
def test_the_papers_gains_are_judged_safe_at_200_hz_and_at_1_khz(period):
    assert unsafe_gains(HIP, PAPER, period) is None
    assert loop_damping(HIP, PAPER, period) > STABILITY_DAMPING_MIN


def test_gains_judged_safe_settle_the_nonlinear_loop_and_unsafe_ones_do_not():
    period = 0.005
    fast = dataclasses.replace(PAPER, kp=2.0 * PAPER.kp)
    unstable = dataclasses.replace(PAPER, kp=4.3 * PAPER.kp)
    assert unsafe_gains(HIP, fast, period) is None
    reason = unsafe_gains(HIP, unstable, period)
    assert reason is not None and 'unstable' in reason and 'kp 150500' in reason
    for gains in (PAPER, fast):
        error = step_response(gains, period)
        # Settled: still (the load and the leakage leave a P loop's offset, 0.3 mm here).
        assert np.ptp(error[-40:]) < 0.02e-3 and np.max(np.abs(error[-40:])) < 0.5e-3
    error = step_response(unstable, period)
    early, late = (np.ptp(error[i:i + 40]) for i in (60, len(error) - 40))
    assert late > 0.5e-3 and late > early  # an oscillation that grows, not one that settles


def test_a_speed_limit_above_the_motor_top_speed_is_unsafe():
    reason = unsafe_gains(HIP, dataclasses.replace(PAPER, speed_limit=1.01 * HIP.motor_speed_max),
                          0.005)
    assert reason is not None and 'motor top speed' in reason


def test_a_period_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match='period'):
        loop_damping(HIP, PAPER, 0.0)

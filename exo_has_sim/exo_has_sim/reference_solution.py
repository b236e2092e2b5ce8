"""Reference solution with scipy's solve_ivp, for checking the fast simulator.

The same right-hand side (:func:`exo_has_sim.model.rhs`) is integrated piecewise between the
instants where a held input changes (sample instants, and those shifted by a transport delay),
with a variable-step implicit method at tight tolerances.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.integrate import solve_ivp

from exo_has_sim import model, model_jacobian
from exo_has_sim.control_law import pd_speed_command
from exo_has_sim.errors import SimulationError
from exo_has_sim.parameters import HasParameters


def _jacobian_function(prm: np.ndarray, command: float, load: float):  # type: ignore[no-untyped-def]
    """Full Jacobian for solve_ivp (cumulative volumes feed nothing back: zero columns).

    It only steers the implicit solver's Newton iterations, not its accuracy.
    """
    dynamic = np.empty((model.N_STATE, model.N_DYNAMIC))

    def jac(_t: float, state: np.ndarray) -> np.ndarray:
        model_jacobian.jacobian(state, command, load, prm, dynamic)
        full = np.zeros((model.N_STATE, model.N_STATE))
        full[:, :model.N_DYNAMIC] = dynamic
        return full

    return jac


# Absolute tolerance per state: m, m/s, Pa, rad/s, -, m^3, rad/s^2, then volumes in m^3.
_ATOL = np.array([1e-10, 1e-9, 1e-2, 1e-7, 1e-10, 1e-16, 1e-4, 1e-2, *([1e-16] * 5)])


def simulate_reference(params: HasParameters, y0: np.ndarray, n_cmd: np.ndarray,
                       f_load: np.ndarray, period: float, rtol: float = 1e-8,
                       method: str = 'Radau') -> np.ndarray:
    """Integrate one joint under held inputs; return the states at the sample times.

    Parameters
    ----------
    params : HasParameters
        The joint's parameters (its transport delay shifts the commands).
    y0 : np.ndarray
        Initial state, length N_STATE.
    n_cmd, f_load : np.ndarray
        Commands [rad/s] and load forces [N], one per sample period, shape (K,).
    period : float
        Sample period [s].
    rtol : float
        Relative tolerance of solve_ivp.
    method : str
        solve_ivp method.

    Returns
    -------
    np.ndarray
        States at t = k * period, shape (K + 1, N_STATE).

    """
    prm = model.pack(params)
    delay = params.effects.transport_delay
    samples = len(n_cmd)
    sample_times = np.arange(samples + 1) * period
    breaks = np.union1d(sample_times, sample_times[:-1] + delay)
    breaks = breaks[breaks <= sample_times[-1] + 1e-12]
    derivative = np.empty(model.N_STATE)
    y = np.array(y0, dtype=float)
    out = np.empty((samples + 1, model.N_STATE))
    out[0] = y
    for t0, t1 in itertools.pairwise(breaks):
        if t1 - t0 < 1e-12:
            continue
        mid = 0.5 * (t0 + t1)
        index = int(np.floor((mid - delay) / period))
        command = n_cmd[index] if index >= 0 else y0[model.N]
        load = f_load[min(int(np.floor(mid / period)), samples - 1)]

        def fun(_t: float, state: np.ndarray, c: float = command, f: float = load) -> np.ndarray:
            model.rhs(state, c, f, prm, derivative)
            return np.array(derivative)

        jac = _jacobian_function(prm, command, load) if method in ('Radau', 'BDF') else None
        solution = solve_ivp(fun, (t0, t1), y, method=method, rtol=rtol, atol=_ATOL, jac=jac)
        if not solution.success:
            msg = f'solve_ivp failed at t = {t0:.4f} s: {solution.message}'
            raise SimulationError(msg)
        y = solution.y[:, -1]
        sample = round(t1 / period)
        if abs(sample * period - t1) < 1e-9:
            out[sample] = y
    return out


def simulate_reference_closed_loop(params: HasParameters, y0: np.ndarray, x_ref: np.ndarray,
                                   v_ref: np.ndarray, f_load: np.ndarray, gains: np.ndarray,
                                   period: float, rtol: float = 1e-8,
                                   method: str = 'Radau') -> np.ndarray:
    """Integrate one joint under the sampled PD law of ``simulate_closed_loop``.

    The controller acts every ``period`` on the sampled position, as in the fast simulator;
    solve_ivp integrates between two actions. A transport delay is refused.

    Returns
    -------
    np.ndarray
        States at the controller instants, shape (K + 1, N_STATE).

    """
    if params.effects.transport_delay:
        msg = 'simulate_reference_closed_loop does not model a transport delay; set it to 0'
        raise SimulationError(msg)
    prm = model.pack(params)
    derivative = np.empty(model.N_STATE)
    samples = len(x_ref)
    kp, kd, kff = (float(g) for g in np.asarray(gains, dtype=float).reshape(-1)[:3])
    limit = params.motor_speed_max
    y = np.array(y0, dtype=float)
    out = np.empty((samples + 1, model.N_STATE))
    out[0] = y
    previous = y[model.X]
    for k in range(samples):
        measured = y[model.X]
        velocity = (measured - previous) / period if k > 0 else 0.0
        previous = measured
        command = pd_speed_command(kp, kd, kff, limit, float(x_ref[k]), float(v_ref[k]),
                                   float(measured), velocity)

        def fun(_t: float, state: np.ndarray, c: float = command,
                f: float = float(f_load[k])) -> np.ndarray:
            model.rhs(state, c, f, prm, derivative)
            return np.array(derivative)

        jac = _jacobian_function(prm, command, float(f_load[k])) \
            if method in ('Radau', 'BDF') else None
        solution = solve_ivp(fun, (k * period, (k + 1) * period), y, method=method, rtol=rtol,
                             atol=_ATOL, jac=jac)
        if not solution.success:
            msg = f'solve_ivp failed at t = {k * period:.4f} s: {solution.message}'
            raise SimulationError(msg)
        y = solution.y[:, -1]
        out[k + 1] = y
    return out

"""The compiled integrator of the HAS model: N joints, open loop or under the sampled PD law.

The pressure dynamics are stiff (the relief and free-mode passages discharge the chamber in
about 0.1 ms, the end stops ring at 100 Hz), so an explicit method would need steps of a few
microseconds. The integrator is the two-stage, second-order, L-stable Rosenbrock method ROS2
(Verwer, Spee, Blom, Hundsdorfer 1999): linearly implicit (no Newton iterations), with the
Jacobian of the dynamic states (:func:`exo_has_sim.model_jacobian.jacobian`) and an
in-place LU solve, compiled with numba. The step size is controlled with the method's
embedded first-order solution: a fixed 1 ms step overshot by tens of MPa where the relief
valve opens within a step, and a fixed step small enough everywhere cost several times more.
bench/simulator.py measures speed and error against solve_ivp. Held inputs change only at
interval boundaries (sample instants, and those shifted by a transport delay), where steps
are cut. The five
cumulative-volume states are carried through the same stages, so the mass balance holds to
rounding.

The functions compile the model (:mod:`exo_has_sim.model`, :mod:`exo_has_sim.model_jacobian`)
and the PD law (:mod:`exo_has_sim.control_law`) into themselves; their cache goes stale with
those sources too (:mod:`exo_has_sim.compiled`). The batch runs are in
:mod:`exo_has_sim.simulate`, the step-by-step plant in :mod:`exo_has_sim.plant_simulator`.
"""

from __future__ import annotations

import math

import numpy as np

from exo_has_sim import control_law, model, model_jacobian
from exo_has_sim.compiled import compiled
from exo_has_sim.errors import SimulationError

#: The modules the functions here compile in.
_INLINED = (model, model_jacobian, control_law)

#: The controller's PD law (:mod:`exo_has_sim.control_law`), compiled for the closed loop.
_pd_speed_command = compiled()(control_law.pd_speed_command)

GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
#: Steps taken on one factorisation of ``I - gamma h J`` at most (:func:`_advance`).
REUSE = 8.0
#: Default largest integration step [s].
DEFAULT_STEP = 2.0e-3
#: Default relative tolerance of the step-size control (bench/simulator.py: about 0.1 to 0.2 mm
#: of position error in walking against solve_ivp at rtol 1e-10, where 0.65 mm is allowed).
DEFAULT_RTOL = 1.0e-2
#: Default absolute tolerance per dynamic state (m, m/s, Pa, rad/s, -, m^3, rad/s^2, Pa).
ATOL = np.array([1e-6, 1e-4, 1e4, 1e-1, 1e-3, 1e-9, 1e2, 1e4])


@compiled(*_INLINED)
def _lu(a: np.ndarray, pivots: np.ndarray) -> None:
    """LU-factorise a small square matrix in place with partial pivoting."""
    n = a.shape[0]
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        pivots[col] = pivot
        if pivot != col:
            for k in range(n):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
        inv = 1.0 / a[col, col]
        for row in range(col + 1, n):
            a[row, col] *= inv
            factor = a[row, col]
            if factor != 0.0:
                for k in range(col + 1, n):
                    a[row, k] -= factor * a[col, k]


@compiled(*_INLINED)
def _lu_solve(a: np.ndarray, pivots: np.ndarray, b: np.ndarray) -> None:
    """Solve with the factors of :func:`_lu`; b becomes the solution."""
    n = a.shape[0]
    for col in range(n):  # the factorisation swapped whole rows: permute b first
        pivot = pivots[col]
        if pivot != col:
            b[col], b[pivot] = b[pivot], b[col]
    for col in range(n):
        for row in range(col + 1, n):
            b[row] -= a[row, col] * b[col]
    for row in range(n - 1, -1, -1):
        acc = b[row]
        for k in range(row + 1, n):
            acc -= a[row, k] * b[k]
        b[row] = acc / a[row, row]


# Work arrays of one integration: rows of ``work`` (length N_STATE each) and the matrices.
_F0, _FP, _YP, _K1, _K2, _YN = range(6)


@compiled(*_INLINED)
def _ros2_trial(y: np.ndarray, h: float, n_cmd: float, f_load: float, prm: np.ndarray,
                work: np.ndarray, jac: np.ndarray, pivots: np.ndarray, lu: np.ndarray,
                atol: np.ndarray, rtol: float, fresh: bool) -> float:
    """One ROS2 step of length h from y into work[_YN]; return the scaled error estimate.

    ``fresh``: evaluate the Jacobian at y and factorise ``I - gamma h J``; otherwise reuse the
    factors (and the Jacobian) of an earlier step of the same length (:func:`_advance`).
    """
    ns = y.shape[0]
    nd = model_jacobian.implicit_states(prm)
    f0, fp, yp, k1, k2, yn = work[_F0], work[_FP], work[_YP], work[_K1], work[_K2], work[_YN]
    gh = GAMMA * h
    factors = lu[:nd, :nd]
    if fresh:
        model_jacobian.rhs_and_jacobian(y, n_cmd, f_load, prm, f0, jac)
        for i in range(nd):
            for k in range(nd):
                factors[i, k] = -gh * jac[i, k]
            factors[i, i] += 1.0
        _lu(factors, pivots)
    else:
        model.rhs(y, n_cmd, f_load, prm, f0)
    for i in range(nd):
        k1[i] = f0[i]
    _lu_solve(factors, pivots, k1[:nd])
    for i in range(nd, ns):
        acc = f0[i]
        for k in range(nd):
            acc += gh * jac[i, k] * k1[k]
        k1[i] = acc
    for i in range(ns):
        yp[i] = y[i] + h * k1[i]
    model.rhs(yp, n_cmd, f_load, prm, fp)
    for i in range(nd):
        k2[i] = fp[i] - 2.0 * k1[i]
    _lu_solve(factors, pivots, k2[:nd])
    for i in range(nd, ns):
        acc = fp[i] - 2.0 * k1[i]
        for k in range(nd):
            acc += gh * jac[i, k] * k2[k]
        k2[i] = acc
    error = 0.0
    for i in range(ns):
        yn[i] = y[i] + 1.5 * h * k1[i] + 0.5 * h * k2[i]
    for i in range(nd):
        # Difference to the embedded first-order solution y + h k1.
        local = abs(0.5 * h * (k1[i] + k2[i])) / (atol[i] + rtol * abs(yn[i]))
        error = max(error, local)
    return error


@compiled(*_INLINED)
def _advance(y: np.ndarray, span: float, step: np.ndarray, n_cmd: float, f_load: float,
             prm: np.ndarray, work: np.ndarray, jac: np.ndarray,
             pivots: np.ndarray, lu: np.ndarray, atol: np.ndarray, rtol: float,
             max_step: float) -> int:
    """Integrate y over ``span`` seconds with adaptive ROS2 steps; return the steps taken.

    ``step`` carries from one call to the next: [0] the step size, [1] the step length the
    factors in ``lu`` were made for (0: none), [2] the steps taken on them. ROS2 is of order
    two whatever matrix stands for the Jacobian (a W-method, Verwer et al. 1999), so a step
    of the same length reuses the factors of an earlier one, at most :data:`REUSE` steps on,
    and a step rejected on old factors is tried again on new ones before it is shortened.
    """
    t = 0.0
    h = min(step[0], max_step)
    taken = 0
    while t < span * (1.0 - 1e-12):
        last = t + h >= span
        trial = span - t if last else h
        fresh = trial != step[1] or step[2] >= REUSE
        error = _ros2_trial(y, trial, n_cmd, f_load, prm, work, jac, pivots, lu, atol,
                            rtol, fresh)
        if fresh:
            step[1] = trial
            step[2] = 0.0
        if error <= 1.0 or trial < 1e-9:
            for i in range(y.shape[0]):
                y[i] = work[_YN, i]
            t += trial
            taken += 1
            step[2] += 1.0
            grow = 0.9 / math.sqrt(max(error, 1e-10))
            if not last:
                h = min(trial * min(2.0, max(0.5, grow)), max_step)
        elif not fresh:
            step[2] = REUSE  # the same step again, on factors made at its start
        else:
            h = trial * max(0.2, 0.9 / math.sqrt(error))
    step[0] = h
    return taken


@compiled(*_INLINED)
def fresh_step(max_step: float) -> np.ndarray:
    """Return the step state of :func:`_advance` for a new joint: no factors yet."""
    return np.array([max_step, 0.0, 0.0])


@compiled(*_INLINED)
def _workspace(ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Allocate the work arrays of :func:`_advance` for a state of length ns."""
    nd = model.N_DYNAMIC
    return (np.empty((6, ns)), np.empty((ns, nd)), np.empty(nd, dtype=np.int64),
            np.empty((nd, nd)))


@compiled(*_INLINED)
def _advance_period(y: np.ndarray, commands: np.ndarray, joint: int, k: int, lag: int,
                    shift: float, initial: float, period: float, step: np.ndarray,
                    f_load: float, prm: np.ndarray, work: np.ndarray, jac: np.ndarray,
                    pivots: np.ndarray, lu: np.ndarray, atol: np.ndarray, rtol: float,
                    max_step: float) -> int:
    """Advance one joint over sample period k under its delayed, held commands.

    A command given at sample i acts from ``i * period + delay``, with ``delay = lag * period
    + shift``: within period k, command k - lag - 1 acts for ``shift`` seconds, then k - lag.
    Before the first command the drive follows ``initial``.
    """
    first, second = k - lag - 1, k - lag
    c1 = commands[first, joint] if first >= 0 else initial
    c2 = commands[second, joint] if second >= 0 else initial
    taken = 0
    if shift > 1e-12:
        taken += _advance(y, shift, step, c1, f_load, prm, work, jac, pivots, lu, atol, rtol,
                          max_step)
    taken += _advance(y, period - shift, step, c2, f_load, prm, work, jac, pivots, lu, atol,
                      rtol, max_step)
    return taken


@compiled(*_INLINED, nogil=True)
def open_loop(y0: np.ndarray, prm: np.ndarray, n_cmd: np.ndarray, f_load: np.ndarray,
              period: float, delay: np.ndarray, atol: np.ndarray,
              rtol: float, max_step: float, out: np.ndarray) -> int:
    """Integrate N joints under held, delayed commands; write the samples into ``out``.

    ``y0`` (N, N_STATE), ``prm`` (N, N_PACKED), ``n_cmd`` and ``f_load`` (K, N), ``delay``
    (N,) [s]; ``out`` (K + 1, N, N_STATE). Return the steps taken. Releases the interpreter's
    lock (:func:`exo_has_sim.simulate.integrate_packed` runs blocks of joints in threads).
    """
    joints, ns = y0.shape
    samples = n_cmd.shape[0]
    y = y0.copy()
    out[0] = y
    work, jac, pivots, lu = _workspace(ns)
    taken = 0
    for j in range(joints):
        step = fresh_step(max_step)
        lag = math.floor(delay[j] / period + 1e-9)
        shift = delay[j] - lag * period
        for k in range(samples):
            taken += _advance_period(y[j], n_cmd, j, k, lag, shift, y0[j, model.N], period,
                                     step, f_load[k, j], prm[j], work, jac, pivots, lu, atol,
                                     rtol, max_step)
            out[k + 1, j] = y[j]
    return taken


@compiled(*_INLINED)
def closed_loop(y0: np.ndarray, prm: np.ndarray, x_ref: np.ndarray, v_ref: np.ndarray,
                f_load: np.ndarray, gains: np.ndarray, period: float,
                delay: np.ndarray, atol: np.ndarray, rtol: float,
                max_step: float, out: np.ndarray, commands: np.ndarray) -> int:
    """Integrate N joints under the sampled PD law; write samples and commands into the outputs.

    ``gains`` (N, 3) ``[kp, kd, kff]``, ``x_ref``, ``v_ref``, ``f_load`` (K, N); ``out``
    (K + 1, N, N_STATE), ``commands`` (K, N). Return the steps taken.
    """
    joints, ns = y0.shape
    samples = x_ref.shape[0]
    y = y0.copy()
    out[0] = y
    work, jac, pivots, lu = _workspace(ns)
    taken = 0
    for j in range(joints):
        step = fresh_step(max_step)
        previous = y[j, model.X]
        limit = prm[j, model.I_NMAX]
        lag = math.floor(delay[j] / period + 1e-9)
        shift = delay[j] - lag * period
        for k in range(samples):
            measured = y[j, model.X]
            velocity = (measured - previous) / period if k > 0 else 0.0
            previous = measured
            commands[k, j] = _pd_speed_command(gains[j, 0], gains[j, 1], gains[j, 2], limit,
                                               x_ref[k, j], v_ref[k, j], measured, velocity)
            taken += _advance_period(y[j], commands, j, k, lag, shift, y0[j, model.N], period,
                                     step, f_load[k, j], prm[j], work, jac, pivots, lu, atol,
                                     rtol, max_step)
            out[k + 1, j] = y[j]
    return taken


@compiled(*_INLINED)
def advance_all(y: np.ndarray, span: float, steps: np.ndarray, n_cmd: np.ndarray,
                f_load: np.ndarray, prm: np.ndarray, atol: np.ndarray, rtol: float,
                max_step: float) -> int:
    """Advance each joint (a row of y) over ``span`` seconds under its held command and load.

    ``steps`` holds a :func:`fresh_step` row per joint, carried from call to call; return the
    steps taken.
    """
    work, jac, pivots, lu = _workspace(y.shape[1])
    taken = 0
    for j in range(y.shape[0]):
        steps[j, 1] = 0.0  # a new workspace: no factors to reuse
        taken += _advance(y[j], span, steps[j], n_cmd[j], f_load[j], prm[j], work, jac,
                          pivots, lu, atol, rtol, max_step)
    return taken


def check_steps(period: float, max_step: float, rtol: float) -> None:
    """Raise :class:`SimulationError` unless period and max_step are positive, rtol in (0, 1)."""
    if not period > 0.0 or not max_step > 0.0 or not 0.0 < rtol < 1.0:
        msg = (f'sample period {period} s and largest step {max_step} s must be positive and '
               f'rtol {rtol} within (0, 1)')
        raise SimulationError(msg)

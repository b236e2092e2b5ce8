"""The compiled integrator of the HAS model: N joints, open loop or under the sampled PD law.

The pressure dynamics are stiff (the relief and free-mode passages discharge the chamber in
about 0.1 ms, the end stops ring at 100 Hz), so an explicit method would need steps of a few
microseconds. The integrators are linearly implicit Rosenbrock methods (no Newton
iterations), with the Jacobian of the dynamic states
(:func:`exo_has_sim.model_jacobian.jacobian`) and an in-place LU solve, compiled with numba;
both are W-methods, of their order whatever matrix stands for the Jacobian, so the factors of
one step serve the next few of the same length. The open loop (the diagnosis's simulations)
takes the four-stage, third-order, L-stable ROS34PW2 (Rang and Angermann 2005); the closed
loop and the step-by-step plant the two-stage, second-order, L-stable ROS2 (Verwer, Spee,
Blom, Hundsdorfer 1999), whose step is the cheaper where a 1 ms control interval takes one
step anyway. One stepping routine serves
both (:func:`_advance`, the methods' coefficients in :data:`ROS34PW2` and :data:`ROS2`). The
step size is controlled with each method's embedded solution of one order less: a fixed 1 ms
step overshot by tens of MPa where the relief valve opens within a step, and a fixed step
small enough everywhere cost several times more. On the diagnosis's calls ROS2's step was held
down by its first-order error estimate: ROS34PW2 takes a third of its steps, for 2.3 times
less CPU at less error (bench/integrator.py, bench/README.md).
bench/simulator.py measures speed and error against solve_ivp. Held inputs change only at
interval boundaries (sample instants, and those shifted by a transport delay), where steps
are cut. The five cumulative-volume states are carried through the same stages, so the mass
balance holds to rounding.

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

#: ROS34PW2 as published (Rang and Angermann 2005, BIT 45, 761-787), in the form of Hairer and
#: Wanner (Solving ODEs II, IV.7): stage i solves ``(I - gamma h J) k_i = h f(y + sum_j
#: alpha_ij k_j) + h J sum_j gamma_ij k_j``; the step is ``y + sum_i b_i k_i``, the embedded
#: second-order solution ``y + sum_i b_hat_i k_i``. ``ROS_GAMMA`` holds gamma_ij with gamma on
#: its diagonal. test_integrator.py checks the orders, with the exact Jacobian and without.
ROS_ALPHA = np.array([[0.0, 0.0, 0.0, 0.0],
                      [8.7173304301691801e-01, 0.0, 0.0, 0.0],
                      [8.4457060015369423e-01, -1.1299064236484185e-01, 0.0, 0.0],
                      [0.0, 0.0, 1.0, 0.0]])
ROS_GAMMA = np.array([[4.3586652150845900e-01, 0.0, 0.0, 0.0],
                      [-8.7173304301691801e-01, 4.3586652150845900e-01, 0.0, 0.0],
                      [-9.0338057013044082e-01, 5.4180672388095326e-02, 4.3586652150845900e-01,
                       0.0],
                      [2.4212380706095346e-01, -1.2232505839045147e+00, 5.4526025533510214e-01,
                       4.3586652150845900e-01]])
ROS_B = np.array([2.4212380706095346e-01, -1.2232505839045147e+00, 1.5452602553351020e+00,
                  4.3586652150845900e-01])
ROS_B_HAT = np.array([3.7810903145819369e-01, -9.6042292212423178e-02, 5.0e-01,
                      2.1793326075422950e-01])
#: A method as :func:`_advance` takes it (:func:`_method`).
Method = tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float, float]


def transformed(alpha: np.ndarray, gamma: np.ndarray, b: np.ndarray,
                b_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return a Rosenbrock method's coefficients in the variables ``u_i = sum_j gamma_ij k_j``.

    In them a stage needs no product with the Jacobian (Hairer and Wanner, IV.7):
    ``(I - gamma h J) u_i = gamma h f(y + sum_j a_ij u_j) + sum_j c_ij u_j``, the step is
    ``y + sum_i m_i u_i`` and its error estimate ``sum_i e_i u_i``.

    Parameters
    ----------
    alpha, gamma : np.ndarray
        The method's stage coefficients (s x s, gamma with its diagonal).
    b, b_hat : np.ndarray
        The weights of the solution and of the embedded one (length s).

    Returns
    -------
    tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
        ``a``, ``c`` (gamma folded in), ``m`` and ``e``.

    """
    inverse = np.linalg.inv(gamma)
    diagonal = np.diag(gamma)
    a = alpha @ inverse
    c = diagonal[:, None] * (np.diag(1.0 / diagonal) - inverse)
    return a, c, b @ inverse, (b - b_hat) @ inverse


def _method(alpha: np.ndarray, gamma: np.ndarray, b: np.ndarray, b_hat: np.ndarray,
            error_order: float, pi: bool) -> Method:
    """Return a method as :func:`_advance` takes it.

    The tuple holds gamma, the :func:`transformed` a, c, m and e, and the exponents of the
    step-size controller, ``h_new = 0.9 h error ** -k_error * previous_error ** k_previous``:
    ``error_order`` is the embedded solution's order plus one (the local error estimate scales
    as h to this power), ``pi`` takes Gustafsson's PI controller (1991, ``k_error = 0.7 /
    error_order``, ``k_previous = 0.4 / error_order``) instead of the plain one.
    """
    k_error = (0.7 if pi else 1.0) / error_order
    k_previous = 0.4 / error_order if pi else 0.0
    return (float(gamma[0, 0]), *transformed(alpha, gamma, b, b_hat), 1.0 / error_order,
            k_error, k_previous)


#: ROS34PW2 (:data:`ROS_ALPHA`), for the open loop: its steps are long, and a third-order step
#: costs four right-hand sides and solves where ROS2's costs two. Its PI controller rejected
#: half as many steps as the plain one on the diagnosis's calls, with less error.
ROS34PW2 = _method(ROS_ALPHA, ROS_GAMMA, ROS_B, ROS_B_HAT, 3.0, True)
_G2 = 1.0 + 1.0 / math.sqrt(2.0)
#: ROS2 (Verwer, Spee, Blom, Hundsdorfer 1999), L-stable and a W-method of order two, its
#: embedded solution the first stage's (of order one), for the closed loop: a control interval
#: of 1 ms takes about one step of either, and ROS2's is the cheaper. Its controller is the
#: plain one: in walking at 1 kHz the PI controller, held back by the small errors of earlier
#: intervals, took 1.6 steps per interval where the plain one takes 1.1.
ROS2 = _method(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[_G2, 0.0], [-2.0 * _G2, _G2]]),
               np.array([0.5, 0.5]), np.array([1.0, 0.0]), 2.0, False)
#: Stages of the longest method (the rows of the work arrays).
_MAX_STAGES = 4
#: Steps taken on one factorisation of ``I - gamma h J`` at most (:func:`_advance`).
REUSE = 8.0
#: Longest step that may cross into an end stop or open or close a cavitation pocket [s]
#: (:func:`_advance`).
EVENT_STEP = 1.0e-5
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


# Work arrays of one integration: rows of ``work`` (length N_STATE each), then one per stage.
_F, _YS, _YN, _U = range(4)


@compiled(*_INLINED)
def _trial(method: Method, y: np.ndarray, h: float, n_cmd: float, f_load: float,
           prm: np.ndarray, work: np.ndarray, jac: np.ndarray, pivots: np.ndarray,
           lu: np.ndarray, atol: np.ndarray, rtol: float, fresh: bool) -> float:
    """One step of ``method`` of length h from y into work[_YN]; return the scaled error estimate.

    ``fresh``: evaluate the Jacobian at y and factorise ``I - gamma h J``; otherwise reuse the
    factors (and the Jacobian) of an earlier step of about the same length (:func:`_advance`).
    """
    gamma, a, c, m, e = method[0], method[1], method[2], method[3], method[4]
    stages = m.shape[0]
    ns = y.shape[0]
    nd = model_jacobian.implicit_states(prm)
    f, ys, yn = work[_F], work[_YS], work[_YN]
    gh = gamma * h
    factors = lu[:nd, :nd]
    if fresh:
        model_jacobian.rhs_and_jacobian(y, n_cmd, f_load, prm, f, jac)
        for i in range(nd):
            for k in range(nd):
                factors[i, k] = -gh * jac[i, k]
            factors[i, i] += 1.0
        _lu(factors, pivots)
    else:
        model.rhs(y, n_cmd, f_load, prm, f)
    for stage in range(stages):
        if stage > 0:
            for i in range(ns):
                acc = y[i]
                for j in range(stage):
                    acc += a[stage, j] * work[_U + j, i]
                ys[i] = acc
            model.rhs(ys, n_cmd, f_load, prm, f)
        u = work[_U + stage]
        for i in range(ns):
            acc = gh * f[i]
            for j in range(stage):
                acc += c[stage, j] * work[_U + j, i]
            u[i] = acc
        _lu_solve(factors, pivots, u[:nd])
        # The other states do not enter the right-hand side: their rows of I - gamma h J are
        # the identity but for the coupling to the dynamic states, solved here by substitution.
        for i in range(nd, ns):
            acc = u[i]
            for k in range(nd):
                acc += gh * jac[i, k] * u[k]
            u[i] = acc
    for i in range(ns):
        acc = y[i]
        for j in range(stages):
            acc += m[j] * work[_U + j, i]
        yn[i] = acc
    error = 0.0
    for i in range(nd):
        local = 0.0
        for j in range(stages):
            local += e[j] * work[_U + j, i]
        error = max(error, abs(local) / (atol[i] + rtol * abs(yn[i])))
    return error


@compiled(*_INLINED)
def _regime(y: np.ndarray, prm: np.ndarray) -> int:
    """Return the number of the piece of the right-hand side y is on (end stop, pocket).

    Entering an end stop sets its damping force in at once, and a pocket's opening or closing
    switches the pressure's law: jumps that the error estimate, made of the same stages, can
    miss (on a captured diagnosis call a step into an end stop was accepted and left the
    position 2 mm off).
    """
    x = y[model.X]
    zone = 0 if x < 0.0 else (2 if x > prm[model.I_STROKE] else 1)
    return zone + (3 if y[model.VOID] > model.VOID_THRESHOLD else 0)


@compiled(*_INLINED)
def _advance(method: Method, y: np.ndarray, span: float, step: np.ndarray, n_cmd: float,
             f_load: float, prm: np.ndarray, work: np.ndarray, jac: np.ndarray,
             pivots: np.ndarray, lu: np.ndarray, atol: np.ndarray, rtol: float,
             max_step: float) -> int:
    """Integrate y over ``span`` seconds in adaptive steps of ``method``; return the steps taken.

    ``step`` carries from one call to the next: [0] the step size, [1] the step length the
    factors in ``lu`` were made for (0: none), [2] the steps taken on them, [3] the error
    estimate of the last step taken (0: none). The rest of the span is cut into equal steps
    no longer than the step size, so that no short last step needs factors of its own, and a
    step of the same length reuses the factors of an earlier one, at most :data:`REUSE` steps
    on; a step rejected on old factors is tried again on new ones before it is shortened. The
    step size follows the method's controller (:func:`_method`). A step that changes
    :func:`_regime` is taken only if at most :data:`EVENT_STEP` long.
    """
    inverse_order, k_error, k_previous = method[5], method[6], method[7]
    t = 0.0
    h = min(step[0], max_step)
    taken = 0
    while t < span * (1.0 - 1e-12):
        remaining = span - t
        count = math.ceil(remaining / h * (1.0 - 1e-6))
        trial = remaining / count
        fresh = abs(trial - step[1]) > 1e-9 * trial or step[2] >= REUSE
        error = _trial(method, y, trial, n_cmd, f_load, prm, work, jac, pivots, lu, atol,
                       rtol, fresh)
        if fresh:
            step[1] = trial
            step[2] = 0.0
        crossed = trial > EVENT_STEP and _regime(y, prm) != _regime(work[_YN], prm)
        if (error <= 1.0 and not crossed) or trial < 1e-9:
            for i in range(y.shape[0]):
                y[i] = work[_YN, i]
            t += trial
            taken += 1
            step[2] += 1.0
            error = max(error, 1e-10)
            if step[3] > 0.0:
                grow = 0.9 * error ** -k_error * step[3] ** k_previous
            else:
                grow = 0.9 * error ** -inverse_order
            step[3] = error
            grown = min(trial * min(2.0, max(0.5, grow)), max_step)
            # A span's last step may be shorter than the step size, and its error then says
            # nothing against the longer step: it may let the step size grow, not shrink it.
            h = max(h, grown) if count == 1 else grown
        elif crossed:
            h = max(0.25 * trial, 0.999 * EVENT_STEP)
        elif not fresh:
            step[2] = REUSE  # the same step again, on factors made at its start
        else:
            h = trial * max(0.2, 0.9 * error ** -inverse_order)
    step[0] = h
    return taken


@compiled(*_INLINED)
def fresh_step(max_step: float) -> np.ndarray:
    """Return the step state of :func:`_advance` for a new joint: no factors yet."""
    return np.array([max_step, 0.0, 0.0, 0.0])


@compiled(*_INLINED)
def _workspace(ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Allocate the work arrays of :func:`_advance` for a state of length ns."""
    nd = model.N_DYNAMIC
    return (np.empty((_U + _MAX_STAGES, ns)), np.empty((ns, nd)), np.empty(nd, dtype=np.int64),
            np.empty((nd, nd)))


@compiled(*_INLINED)
def _advance_period(method: Method, y: np.ndarray, commands: np.ndarray, joint: int, k: int,
                    lag: int, shift: float, initial: float, period: float, step: np.ndarray,
                    f_load: float, prm: np.ndarray, work: np.ndarray, jac: np.ndarray,
                    pivots: np.ndarray, lu: np.ndarray, atol: np.ndarray, rtol: float,
                    max_step: float) -> int:
    """Advance one joint over sample period k under its delayed, held commands, by ``method``.

    A command given at sample i acts from ``i * period + delay``, with ``delay = lag * period
    + shift``: within period k, command k - lag - 1 acts for ``shift`` seconds, then k - lag.
    Before the first command the drive follows ``initial``.
    """
    first, second = k - lag - 1, k - lag
    c1 = commands[first, joint] if first >= 0 else initial
    c2 = commands[second, joint] if second >= 0 else initial
    taken = 0
    if shift > 1e-12:
        taken += _advance(method, y, shift, step, c1, f_load, prm, work, jac, pivots, lu,
                          atol, rtol, max_step)
    taken += _advance(method, y, period - shift, step, c2, f_load, prm, work, jac, pivots, lu,
                      atol, rtol, max_step)
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
            taken += _advance_period(ROS34PW2, y[j], n_cmd, j, k, lag, shift, y0[j, model.N],
                                     period, step, f_load[k, j], prm[j], work, jac, pivots, lu,
                                     atol, rtol, max_step)
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
            taken += _advance_period(ROS2, y[j], commands, j, k, lag, shift, y0[j, model.N],
                                     period, step, f_load[k, j], prm[j], work, jac, pivots, lu,
                                     atol, rtol, max_step)
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
        taken += _advance(ROS2, y[j], span, steps[j], n_cmd[j], f_load[j], prm[j], work, jac,
                          pivots, lu, atol, rtol, max_step)
    return taken


def check_steps(period: float, max_step: float, rtol: float) -> None:
    """Raise :class:`SimulationError` unless period and max_step are positive, rtol in (0, 1)."""
    if not period > 0.0 or not max_step > 0.0 or not 0.0 < rtol < 1.0:
        msg = (f'sample period {period} s and largest step {max_step} s must be positive and '
               f'rtol {rtol} within (0, 1)')
        raise SimulationError(msg)

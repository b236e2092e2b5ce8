"""Fast simulation of N HAS joints, open or closed loop.

The pressure dynamics are stiff (the relief and free-mode passages discharge the chamber in
about 0.1 ms, the end stops ring at 100 Hz), so an explicit method would need steps of a few
microseconds. The integrator is the two-stage, second-order, L-stable Rosenbrock method ROS2
(Verwer, Spee, Blom, Hundsdorfer 1999): linearly implicit (no Newton iterations), with the
Jacobian of the dynamic states (:func:`exo_has_sim.model.jacobian`) and an
in-place LU solve, compiled with numba. The step size is controlled with the method's
embedded first-order solution: a fixed 1 ms step overshot by tens of MPa where the relief
valve opens within a step, and a fixed step small enough everywhere cost several times more.
bench/simulator.py measures speed and error against solve_ivp. Held inputs change only at
interval boundaries (sample instants, and those shifted by a transport delay), where steps
are cut. The five
cumulative-volume states are carried through the same stages, so the mass balance holds to
rounding.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from exo_has_sim import model
from exo_has_sim.control_law import pd_speed_command
from exo_has_sim.errors import SimulationError
from exo_has_sim.parameters import HasParameters


def _drop_stale_compiled_code() -> None:
    """Delete this module's numba cache when model.py or control_law.py changed since.

    numba invalidates a cached function only when its own file changes, but the functions here
    compile the model's right-hand side and the PD law into themselves: after an edit of
    either they would go on running the old code.
    """
    here = Path(__file__).resolve().parent
    cache = here / '__pycache__'
    stamp = cache / 'simulate.model-source.sha256'
    digest = hashlib.sha256(b''.join((here / name).read_bytes()
                                     for name in ('model.py', 'control_law.py'))).hexdigest()
    try:
        if stamp.is_file() and stamp.read_text() == digest:
            return
        for compiled in cache.glob('simulate.*.nb[ic]'):
            compiled.unlink()
        cache.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass  # a read-only install: numba then compiles in memory or keeps its own cache


_drop_stale_compiled_code()

#: The controller's PD law (:mod:`exo_has_sim.control_law`), compiled for the closed loop.
_pd_speed_command = njit(cache=True)(pd_speed_command)

GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
#: Steps taken on one factorisation of ``I - gamma h J`` at most (:func:`_advance`).
REUSE = 8.0
#: Default largest integration step [s].
DEFAULT_STEP = 2.0e-3
#: Default relative tolerance of the step-size control (bench/simulator.py: about 0.1 to 0.2 mm
#: of position error in walking against solve_ivp at rtol 1e-10, where 0.65 mm is allowed).
DEFAULT_RTOL = 1.0e-2
# Absolute tolerance of each dynamic state (m, m/s, Pa, rad/s, -, m^3, rad/s^2, Pa).
_ATOL = np.array([1e-6, 1e-4, 1e4, 1e-1, 1e-3, 1e-9, 1e2, 1e4])


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def _ros2_trial(y: np.ndarray, h: float, n_cmd: float, f_load: float, prm: np.ndarray,
                work: np.ndarray, jac: np.ndarray, pivots: np.ndarray, lu: np.ndarray,
                atol: np.ndarray, rtol: float, fresh: bool) -> float:
    """One ROS2 step of length h from y into work[_YN]; return the scaled error estimate.

    ``fresh``: evaluate the Jacobian at y and factorise ``I - gamma h J``; otherwise reuse the
    factors (and the Jacobian) of an earlier step of the same length (:func:`_advance`).
    """
    ns = y.shape[0]
    nd = model.implicit_states(prm)
    f0, fp, yp, k1, k2, yn = work[_F0], work[_FP], work[_YP], work[_K1], work[_K2], work[_YN]
    gh = GAMMA * h
    factors = lu[:nd, :nd]
    if fresh:
        model.rhs_and_jacobian(y, n_cmd, f_load, prm, f0, jac)
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


@njit(cache=True)
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


@njit(cache=True)
def _fresh_step(max_step: float) -> np.ndarray:
    """Return the step state of :func:`_advance` for a new joint: no factors yet."""
    return np.array([max_step, 0.0, 0.0])


@njit(cache=True)
def _workspace(ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Allocate the work arrays of :func:`_advance` for a state of length ns."""
    nd = model.N_DYNAMIC
    return (np.empty((6, ns)), np.empty((ns, nd)), np.empty(nd, dtype=np.int64),
            np.empty((nd, nd)))


@njit(cache=True)
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


@njit(cache=True, nogil=True)
def _open_loop(y0: np.ndarray, prm: np.ndarray, n_cmd: np.ndarray, f_load: np.ndarray,
               period: float, delay: np.ndarray, atol: np.ndarray,
               rtol: float, max_step: float, out: np.ndarray) -> int:
    joints, ns = y0.shape
    samples = n_cmd.shape[0]
    y = y0.copy()
    out[0] = y
    work, jac, pivots, lu = _workspace(ns)
    taken = 0
    for j in range(joints):
        step = _fresh_step(max_step)
        lag = math.floor(delay[j] / period + 1e-9)
        shift = delay[j] - lag * period
        for k in range(samples):
            taken += _advance_period(y[j], n_cmd, j, k, lag, shift, y0[j, model.N], period,
                                     step, f_load[k, j], prm[j], work, jac, pivots, lu, atol,
                                     rtol, max_step)
            out[k + 1, j] = y[j]
    return taken


@njit(cache=True)
def _closed_loop(y0: np.ndarray, prm: np.ndarray, x_ref: np.ndarray, v_ref: np.ndarray,
                 f_load: np.ndarray, gains: np.ndarray, period: float,
                 delay: np.ndarray, atol: np.ndarray, rtol: float,
                 max_step: float, out: np.ndarray, commands: np.ndarray) -> int:
    joints, ns = y0.shape
    samples = x_ref.shape[0]
    y = y0.copy()
    out[0] = y
    work, jac, pivots, lu = _workspace(ns)
    taken = 0
    for j in range(joints):
        step = _fresh_step(max_step)
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


@dataclass(frozen=True)
class SimulationResult:
    """States of N joints at the sample times.

    Attributes
    ----------
    time : np.ndarray
        Sample times [s], shape (K + 1,), starting at 0.
    states : np.ndarray
        States, shape (K + 1, N, N_STATE) (layout in :mod:`exo_has_sim.model`).
    commands : np.ndarray
        Motor speed commands issued at each sample [rad/s], shape (K, N).

    """

    time: np.ndarray
    states: np.ndarray
    commands: np.ndarray

    @property
    def position(self) -> np.ndarray:
        """Cylinder extension [m], shape (K + 1, N)."""
        return self.states[:, :, model.X]

    @property
    def pressure(self) -> np.ndarray:
        """Rodless chamber pressure [Pa], shape (K + 1, N)."""
        return self.states[:, :, model.PA]


def _packed(params: Sequence[HasParameters]) -> np.ndarray:
    return np.stack([model.pack(p) for p in params])


def _check_steps(period: float, max_step: float, rtol: float) -> None:
    if not period > 0.0 or not max_step > 0.0 or not 0.0 < rtol < 1.0:
        msg = (f'sample period {period} s and largest step {max_step} s must be positive and '
               f'rtol {rtol} within (0, 1)')
        raise SimulationError(msg)


def _as_2d(values: np.ndarray, joints: int, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim == 1:
        array = array[:, None] * np.ones(joints)
    if array.ndim != 2 or array.shape[1] != joints:
        msg = f'{name} must have shape (samples, {joints}), got {array.shape}'
        raise SimulationError(msg)
    if not np.all(np.isfinite(array)):
        msg = f'{name} holds NaN or infinite values'
        raise SimulationError(msg)
    return np.ascontiguousarray(array)


def simulate_open_loop(params: Sequence[HasParameters], y0: np.ndarray, n_cmd: np.ndarray,
                       f_load: np.ndarray, period: float, max_step: float = DEFAULT_STEP,
                       rtol: float = DEFAULT_RTOL) -> SimulationResult:
    """Simulate N joints driven by sampled (zero-order-hold) commands.

    Parameters
    ----------
    params : Sequence[HasParameters]
        One parameter set per joint.
    y0 : np.ndarray
        Initial states, shape (N, N_STATE).
    n_cmd : np.ndarray
        Motor speed commands [rad/s], shape (K, N), held for one period each; a joint's
        transport delay shifts them in time exactly (to the integration step).
    f_load : np.ndarray
        Load forces [N], shape (K, N) or (K,), held likewise (not delayed).
    period : float
        Sample period [s].
    max_step : float
        Largest integration step [s].
    rtol : float
        Relative tolerance of the step-size control.

    """
    joints = len(params)
    commands = _as_2d(n_cmd, joints, 'n_cmd')
    loads = _as_2d(f_load, joints, 'f_load')
    if loads.shape[0] != commands.shape[0]:
        raise SimulationError('n_cmd and f_load must have the same number of samples')
    _check_steps(period, max_step, rtol)
    delay = np.array([p.effects.transport_delay for p in params])
    states = integrate_packed(_packed(params), delay, y0, commands, loads, period,
                              max_step=max_step, rtol=rtol)
    time = np.arange(commands.shape[0] + 1) * period
    return SimulationResult(time, states, commands)


def threads() -> int:
    """Return how many threads :func:`integrate_packed` spreads its joints over.

    ``EXO_HAS_THREADS`` where set (a pool of processes that each integrate sets it to 1),
    else one per processor this process may run on.
    """
    given = os.environ.get('EXO_HAS_THREADS', '').strip()
    if given.isdigit() and int(given) > 0:
        return int(given)
    return len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') \
        else os.cpu_count() or 1


def integrate_packed(packed: np.ndarray, delay: np.ndarray, y0: np.ndarray,
                     n_cmd: np.ndarray, f_load: np.ndarray, period: float,
                     max_step: float = DEFAULT_STEP, rtol: float = DEFAULT_RTOL,
                     atol: np.ndarray | None = None) -> np.ndarray:
    """Integrate N joints open loop from packed parameters; the core of simulate_open_loop.

    For callers that build many parameter sets at once (the diagnosis's candidates): no
    per-joint :class:`HasParameters` and no checks of the inputs' shapes. The joints are
    independent, and the compiled loop releases the interpreter's lock, so they are shared
    among :func:`threads` threads, each integrating a block of them.

    Parameters
    ----------
    packed : np.ndarray
        One :func:`exo_has_sim.model.pack` row per joint, shape (N, N_PACKED).
    delay : np.ndarray
        Transport delay of each joint [s], shape (N,).
    y0, n_cmd, f_load, period, max_step, rtol
        As :func:`simulate_open_loop` (n_cmd and f_load of shape (K, N)).
    atol : np.ndarray or None
        Absolute tolerance of each dynamic state (length N_DYNAMIC); None: the default.

    Returns
    -------
    np.ndarray
        States, shape (K + 1, N, N_STATE).

    Raises
    ------
    SimulationError
        If a joint diverged.

    """
    joints = packed.shape[0]
    y0 = np.ascontiguousarray(y0, dtype=float)
    packed = np.ascontiguousarray(packed)
    delay = np.ascontiguousarray(delay, dtype=float)
    tolerance = _ATOL if atol is None else atol

    def block(first: int, last: int) -> np.ndarray:
        out = np.empty((n_cmd.shape[0] + 1, last - first, model.N_STATE))
        _open_loop(y0[first:last], packed[first:last],
                   np.ascontiguousarray(n_cmd[:, first:last]),
                   np.ascontiguousarray(f_load[:, first:last]), period, delay[first:last],
                   tolerance, rtol, max_step, out)
        return out

    count = min(threads(), max(joints // 8, 1))  # a few joints are not worth a thread
    if count == 1:
        states = block(0, joints)
    else:
        edges = np.linspace(0, joints, count + 1).round().astype(int)
        with ThreadPoolExecutor(count) as pool:
            states = np.concatenate(list(pool.map(block, edges[:-1], edges[1:])), axis=1)
    if not np.all(np.isfinite(states)):
        raise SimulationError('the simulation diverged (NaN or infinite state)')
    return states


def simulate_closed_loop(params: Sequence[HasParameters], y0: np.ndarray, x_ref: np.ndarray,
                         v_ref: np.ndarray, f_load: np.ndarray, gains: np.ndarray,
                         period: float, max_step: float = DEFAULT_STEP,
                         rtol: float = DEFAULT_RTOL) -> SimulationResult:
    """Simulate N joints under sampled PD position control of the cylinders.

    The controller samples the position every ``period`` and commands
    ``kff v_ref + kp (x_ref - x) + kd (v_ref - dx/dt)`` (dx/dt by backward difference of the
    samples), saturated at the motor's top speed; a joint's transport delay holds its commands
    back exactly (the step is cut where a delayed command takes effect).

    Parameters
    ----------
    gains : np.ndarray
        Per joint ``[kp, kd, kff]``: kp [rad/s per m], kd [rad/s per (m/s)], kff [rad/s per
        (m/s)], shape (N, 3).

    """
    joints = len(params)
    refs = _as_2d(x_ref, joints, 'x_ref')
    vels = _as_2d(v_ref, joints, 'v_ref')
    loads = _as_2d(f_load, joints, 'f_load')
    samples = refs.shape[0]
    if vels.shape[0] != samples or loads.shape[0] != samples:
        raise SimulationError('x_ref, v_ref and f_load must have the same number of samples')
    gain_array = np.ascontiguousarray(np.broadcast_to(np.asarray(gains, float), (joints, 3)))
    delay = np.array([p.effects.transport_delay for p in params])
    _check_steps(period, max_step, rtol)
    states = np.empty((samples + 1, joints, model.N_STATE))
    commands = np.empty((samples, joints))
    _closed_loop(np.ascontiguousarray(y0, dtype=float), _packed(params), refs, vels, loads,
                 gain_array, period, delay, _ATOL, rtol, max_step, states, commands)
    if not np.all(np.isfinite(states)):
        raise SimulationError('the simulation diverged (NaN or infinite state)')
    return SimulationResult(np.arange(samples + 1) * period, states, commands)


@njit(cache=True)
def _advance_all(y: np.ndarray, span: float, steps: np.ndarray, n_cmd: np.ndarray,
                 f_load: np.ndarray, prm: np.ndarray, atol: np.ndarray, rtol: float,
                 max_step: float) -> int:
    work, jac, pivots, lu = _workspace(y.shape[1])
    taken = 0
    for j in range(y.shape[0]):
        steps[j, 1] = 0.0  # a new workspace: no factors to reuse
        taken += _advance(y[j], span, steps[j], n_cmd[j], f_load[j], prm[j], work, jac,
                          pivots, lu, atol, rtol, max_step)
    return taken


class PlantSimulator:
    """N joints advanced step by step under held inputs, for a plant node.

    Each call to :meth:`step` holds the given commands and loads for ``dt`` seconds. A joint's
    transport delay holds its commands back in time exactly: the drive acts on a command
    ``transport_delay`` after it was given (before the first one, on the initial motor speed).

    Parameters
    ----------
    params : Sequence[HasParameters]
        One parameter set per joint.
    y0 : np.ndarray
        Initial states, shape (N, N_STATE).

    """

    def __init__(self, params: Sequence[HasParameters], y0: np.ndarray,
                 max_step: float = DEFAULT_STEP, rtol: float = DEFAULT_RTOL) -> None:
        _check_steps(1.0, max_step, rtol)
        self.params = list(params)
        self.state: np.ndarray = np.array(y0, dtype=float, copy=True)
        if self.state.shape != (len(self.params), model.N_STATE):
            msg = f'y0 must have shape ({len(self.params)}, {model.N_STATE})'
            raise SimulationError(msg)
        self.time = 0.0
        self._prm = _packed(self.params)
        self._delay = np.array([p.effects.transport_delay for p in self.params])
        self._steps = np.array([_fresh_step(max_step) for _ in self.params])
        self._max_step = max_step
        self._rtol = rtol
        # Per joint: times at which commands were given, and the commands.
        self._history: list[list[tuple[float, float]]] = [
            [(-np.inf, float(self.state[j, model.N]))] for j in range(len(self.params))]

    def _applied(self, joint: int, t: float) -> float:
        """Command the drive of a joint acts on at time t."""
        moment = t - self._delay[joint]
        value = self._history[joint][0][1]
        for given, command in self._history[joint]:
            if given <= moment + 1e-12:
                value = command
            else:
                break
        return value

    def step(self, n_cmd: np.ndarray, f_load: np.ndarray, dt: float) -> np.ndarray:
        """Give commands [rad/s] and loads [N] (one per joint), advance dt [s], return states.

        Raises
        ------
        SimulationError
            On a non-finite input, a non-positive dt, or a diverged state.

        """
        commands = np.asarray(n_cmd, dtype=float).reshape(-1)
        loads = np.asarray(f_load, dtype=float).reshape(-1)
        joints = len(self.params)
        if commands.shape != (joints,) or loads.shape != (joints,):
            msg = f'n_cmd and f_load need one value per joint ({joints})'
            raise SimulationError(msg)
        # A sum is finite only if every term is (math on one float: this runs at every tick).
        if not math.isfinite(float(commands.sum()) + float(loads.sum())):
            raise SimulationError('n_cmd and f_load must be finite')
        if not dt > 0.0:
            msg = f'dt must be positive, got {dt}'
            raise SimulationError(msg)
        start = self.time
        for j in range(joints):
            self._history[j].append((start, float(commands[j])))
            horizon = start - self._delay[j]  # older commands no longer matter
            while len(self._history[j]) > 2 and self._history[j][1][0] <= horizon:
                self._history[j].pop(0)
        # Cut each joint's step where one of its delayed commands takes effect.
        for j in range(joints):
            cuts = {start, start + dt}
            for given, _ in self._history[j]:
                effect = given + self._delay[j]
                if start < effect < start + dt:
                    cuts.add(effect)
            for t0, t1 in itertools.pairwise(sorted(cuts)):
                _advance_all(self.state[j:j + 1], t1 - t0, self._steps[j:j + 1],
                             np.array([self._applied(j, t0)]), loads[j:j + 1],
                             self._prm[j:j + 1], _ATOL, self._rtol, self._max_step)
        self.time = start + dt
        if not math.isfinite(float(self.state.sum())):
            raise SimulationError('the simulation diverged (NaN or infinite state)')
        return np.array(self.state)

    def valve_modes(self) -> list[int]:
        """Valve mode of each joint now (exo_has_msgs/msg/HasState VALVE_* numbering)."""
        return [model.valve_mode(self.state[j], self._prm[j]) for j in range(len(self.params))]

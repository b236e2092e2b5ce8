"""Batch simulation of N HAS joints, open loop or under the sampled PD law.

The runs check their inputs and hand them to the compiled integrator
(:mod:`exo_has_sim.integrator`, where the method and its tolerances are described); the
diagnosis integrates many packed parameter sets at once with :func:`integrate_packed`, spread
over threads. A plant node advances its joints step by step with
:class:`exo_has_sim.plant_simulator.PlantSimulator` instead.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from exo_has_sim import model
from exo_has_sim.errors import SimulationError
from exo_has_sim.integrator import (
    ATOL,
    DEFAULT_RTOL,
    DEFAULT_STEP,
    check_steps,
    closed_loop,
    open_loop,
)
from exo_has_sim.parameters import HasParameters

#: Fewest joints worth a block of their own in :func:`integrate_packed`.
BLOCK_JOINTS = 8
#: Blocks per thread in :func:`integrate_packed`: joints' step counts differ several-fold
#: (a spool that switches takes more), and a thread that drew the easy ones takes another.
BLOCKS_PER_THREAD = 4
_POOL_PREFIX = 'exo_has_integrate'
_pool: tuple[int, int, ThreadPoolExecutor] | None = None  # (pid, threads, pool)
_pool_lock = threading.Lock()


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
    check_steps(period, max_step, rtol)
    delay = np.array([p.effects.transport_delay for p in params])
    states = integrate_packed(model.pack_joints(params), delay, y0, commands, loads, period,
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
    independent, and the compiled loop releases the interpreter's lock, so blocks of them
    (at least :data:`BLOCK_JOINTS` joints, up to :data:`BLOCKS_PER_THREAD` per thread) go to
    a pool of :func:`threads` threads kept for the process.

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
    tolerance = ATOL if atol is None else atol

    def block(first: int, last: int) -> np.ndarray:
        out = np.empty((n_cmd.shape[0] + 1, last - first, model.N_STATE))
        open_loop(y0[first:last], packed[first:last],
                  np.ascontiguousarray(n_cmd[:, first:last]),
                  np.ascontiguousarray(f_load[:, first:last]), period, delay[first:last],
                  tolerance, rtol, max_step, out)
        return out

    count = threads()
    blocks = min(count * BLOCKS_PER_THREAD, joints // BLOCK_JOINTS)
    if count == 1 or blocks <= 1 or threading.current_thread().name.startswith(_POOL_PREFIX):
        states = block(0, joints)
    else:
        edges = np.linspace(0, joints, blocks + 1).round().astype(int)
        states = np.concatenate(list(_thread_pool(count).map(block, edges[:-1], edges[1:])),
                                axis=1)
    if not np.all(np.isfinite(states)):
        raise SimulationError('the simulation diverged (NaN or infinite state)')
    return states


def _thread_pool(count: int) -> ThreadPoolExecutor:
    """Return the process's pool of ``count`` integrating threads, made on first use.

    Kept from call to call: a diagnosis integrates hundreds of times, and starting the
    threads anew each time cost it 2 of 65 s. A forked child, which has none of its
    parent's threads, and a changed count get a new pool.
    """
    global _pool
    with _pool_lock:
        if _pool is None or _pool[:2] != (os.getpid(), count):
            if _pool is not None and _pool[0] == os.getpid():
                _pool[2].shutdown(wait=False)
            _pool = (os.getpid(), count,
                     ThreadPoolExecutor(count, thread_name_prefix=_POOL_PREFIX))
        return _pool[2]


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
    check_steps(period, max_step, rtol)
    states = np.empty((samples + 1, joints, model.N_STATE))
    commands = np.empty((samples, joints))
    closed_loop(np.ascontiguousarray(y0, dtype=float), model.pack_joints(params), refs, vels,
                loads, gain_array, period, delay, ATOL, rtol, max_step, states, commands)
    if not np.all(np.isfinite(states)):
        raise SimulationError('the simulation diverged (NaN or infinite state)')
    return SimulationResult(np.arange(samples + 1) * period, states, commands)

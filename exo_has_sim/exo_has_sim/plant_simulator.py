"""N HAS joints advanced step by step under held inputs, as a plant node needs them.

Each step integrates with the compiled integrator (:mod:`exo_has_sim.integrator`), cut where a
joint's delayed command takes effect; :mod:`exo_has_sim.simulate` runs whole command sequences
instead.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from exo_has_sim import model
from exo_has_sim.errors import SimulationError
from exo_has_sim.integrator import (
    ATOL,
    DEFAULT_RTOL,
    DEFAULT_STEP,
    advance_all,
    check_steps,
    fresh_step,
)
from exo_has_sim.parameters import HasParameters


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
        check_steps(1.0, max_step, rtol)
        self.params = list(params)
        self.state: np.ndarray = np.array(y0, dtype=float, copy=True)
        if self.state.shape != (len(self.params), model.N_STATE):
            msg = f'y0 must have shape ({len(self.params)}, {model.N_STATE})'
            raise SimulationError(msg)
        self.time = 0.0
        self._prm = model.pack_joints(self.params)
        self._delay = np.array([p.effects.transport_delay for p in self.params])
        self._steps = np.array([fresh_step(max_step) for _ in self.params])
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
                advance_all(self.state[j:j + 1], t1 - t0, self._steps[j:j + 1],
                            np.array([self._applied(j, t0)]), loads[j:j + 1],
                            self._prm[j:j + 1], ATOL, self._rtol, self._max_step)
        self.time = start + dt
        if not math.isfinite(float(self.state.sum())):
            raise SimulationError('the simulation diverged (NaN or infinite state)')
        return np.array(self.state)

    def valve_modes(self) -> list[int]:
        """Valve mode of each joint now (exo_has_msgs/msg/HasState VALVE_* numbering)."""
        return [model.valve_mode(self.state[j], self._prm[j]) for j in range(len(self.params))]

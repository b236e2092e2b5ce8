"""Compile the simulator's integrators into numba's on-disk cache before their first use.

A compiled function (:mod:`exo_has_sim.compiled`) is compiled at its first call in a process
unless the cache holds it for the sources as they are, which takes some 14 s of a core for
the three integrators with the model in them. On a fresh install, or after an edit of the
model, that falls on whatever runs first: the demo's warm-up before it starts its nodes
(:func:`exo_has_bringup.demo.warm_up`, 5.6 s for the plant's integrator), a plant node before
it reports ready, the first diagnosis (8 s for the open loop), the first tests of each
worker at once. ``./run`` calls :func:`compile_integrators` after the build, and once the
cache holds them the call only loads them (0.4 s).

Run: ``python -m exo_has_sim.precompile``.
"""

from __future__ import annotations

import time

import numpy as np

from exo_has_sim import model
from exo_has_sim.parameters import load_parameters
from exo_has_sim.plant import Plant
from exo_has_sim.simulate import simulate_closed_loop, simulate_open_loop

#: Samples of the short runs that make each integrator compile [-], and their period [s].
SAMPLES, PERIOD = 4, 0.005


def compile_integrators() -> float:
    """Run each integrator once on a few samples, as the nodes and the diagnosis call them.

    The open loop (the diagnosis), the closed loop (batch simulations) and the step-by-step
    plant (the plant nodes), with the shipped hip's parameters at mid-stroke: the argument
    types are those of every call, so the cache serves them all.

    Returns
    -------
    float
        Seconds it took (compiling, or loading from the cache).

    """
    started = time.perf_counter()
    params = load_parameters('hip')
    y0 = model.initial_state(params, 0.5 * params.stroke)[None, :]
    zeros = np.zeros((SAMPLES, 1))
    simulate_open_loop([params], y0, zeros, zeros, PERIOD)
    simulate_closed_loop([params], y0, np.full((SAMPLES, 1), 0.5 * params.stroke), zeros,
                         zeros, np.array([[1.0, 0.0, 0.0]]), PERIOD)
    Plant('left_hip', params).warm_up()  # as the plant node and the demo warm theirs
    return time.perf_counter() - started


def main() -> None:
    """Compile the integrators and say how long it took."""
    print(f'exo_has_sim: integrators compiled or loaded in {compile_integrators():.1f} s')


if __name__ == '__main__':
    main()

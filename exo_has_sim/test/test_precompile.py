"""Precompiling the integrators makes the very signatures their callers then use."""

import numpy as np

from exo_has_sim import integrator, model
from exo_has_sim.parameters import load_parameters
from exo_has_sim.plant_simulator import PlantSimulator
from exo_has_sim.precompile import compile_integrators
from exo_has_sim.simulate import integrate_packed, simulate_closed_loop

KERNELS = (integrator.open_loop, integrator.closed_loop, integrator.advance_all)


def test_the_plant_the_batch_runs_and_the_diagnosis_call_only_what_was_precompiled():
    compile_integrators()
    made = {kernel: set(kernel.signatures) for kernel in KERNELS}
    assert all(made.values())
    hip, knee = load_parameters('hip'), load_parameters('knee')
    y0 = np.stack([model.initial_state(p, 0.3 * p.stroke, 300.0) for p in (hip, knee)])
    # A plant node's simulator: two joints, a load each, steps cut by a transport delay.
    plant = PlantSimulator([hip, knee], y0)
    for _ in range(3):
        plant.step([20.0, -15.0], np.array([300.0, 250.0]), 0.005)
    # A batch run under the PD law, references and loads as columns of wider tables.
    references = np.tile(y0[:, model.X], (8, 3))[:, ::3]
    simulate_closed_loop([hip, knee], y0, references, np.zeros((8, 2)),
                         np.full((8, 2), 300.0), np.array([[2000.0, 0.0, 1.0]] * 2), 0.005)
    # The diagnosis's candidates: packed rows, commands sliced out of a record's columns.
    record = np.asfortranarray(np.random.default_rng(1).normal(0.0, 20.0, (8, 6)))
    integrate_packed(model.pack_joints([hip, knee, hip]), np.array([0.0, 0.004, 0.0]),
                     y0[[0, 1, 0]], record[:, ::2], np.full((8, 3), 300.0), 0.005)
    assert {kernel: set(kernel.signatures) for kernel in KERNELS} == made

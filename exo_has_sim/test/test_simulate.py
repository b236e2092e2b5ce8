"""The fast simulator against scipy's solve_ivp (Radau, rtol 1e-8) on walking."""

import numpy as np
import pytest

from exo_has_sim import linear, model
from exo_has_sim.errors import SimulationError
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters
from exo_has_sim.reference_solution import simulate_reference
from exo_has_sim.simulate import simulate_closed_loop, simulate_open_loop

HIP = load_parameters('hip')
ALL_EFFECTS = {'coulomb_friction': 60.0, 'stribeck_friction': 30.0, 'pump_deadzone': 8.0,
                   'transport_delay': 0.0073, 'quadratic_leakage': 2e-21,
                   'relief_crack_pressure': 15e6, 'relief_crack_conductance': 2e-12,
                   'entrained_air': 0.01}
PERIOD = 0.005  # the paper's 200 Hz


def walking(params, duration=10.0, stride_frequency=0.85):
    t = np.arange(round(duration / PERIOD)) * PERIOD
    hip, _ = load_gait_cycle().angles_at(t * stride_frequency)
    x_ref = Linkage.from_parameters(params).position(hip)
    return x_ref, np.gradient(x_ref, PERIOD)


@pytest.mark.parametrize('effects', [{}, ALL_EFFECTS], ids=['effects off', 'all effects on'])
def test_the_fast_simulator_agrees_with_solve_ivp_over_10_s_of_walking(effects):
    params = HIP.with_effects(**effects)
    load = 50.0 * 9.81
    x_ref, v_ref = walking(params)
    loads = np.full(len(x_ref), load)
    y0 = model.initial_state(params, x_ref[0], load)
    gains = np.array([[35e3, 15.0, 1.0 / linear.velocity_gain(params)]])
    closed = simulate_closed_loop([params], y0[None, :], x_ref[:, None], v_ref[:, None], loads,
                                  gains, PERIOD)
    # It walks: this walk asks up to 0.26 m/s, beyond the 0.17 m/s of the top motor speed,
    # so the commands saturate a fifth of the time and the error peaks there.
    assert np.sqrt(np.mean((closed.position[1:, 0] - x_ref) ** 2)) < 0.005
    # Replay the loop's commands open loop, so both integrators see the same inputs.
    commands = closed.commands[:, 0]
    fast = simulate_open_loop([params], y0[None, :], commands[:, None], loads, PERIOD)
    reference = simulate_reference(params, y0, commands, loads, PERIOD, rtol=1e-8)
    error = np.max(np.abs(fast.position[:, 0] - reference[:, model.X]))
    assert error < 0.005 * params.stroke


def test_bad_inputs_are_refused_with_a_clear_message():
    y0 = model.initial_state(HIP, 0.05)[None, :]
    with pytest.raises(SimulationError, match='NaN or infinite'):
        simulate_open_loop([HIP], y0, np.array([[np.nan]]), np.array([0.0]), PERIOD)
    with pytest.raises(SimulationError, match=r'shape \(samples, 1\)'):
        simulate_open_loop([HIP], y0, np.zeros((3, 2)), np.zeros(3), PERIOD)
    with pytest.raises(SimulationError, match='must be positive'):
        simulate_open_loop([HIP], y0, np.zeros((3, 1)), np.zeros(3), 0.0)


def test_joints_are_independent_in_a_vectorised_run():
    knee = load_parameters('knee')
    y0 = np.stack([model.initial_state(HIP, 0.05, 300.0), model.initial_state(knee, 0.06, 0.0)])
    commands = np.column_stack([np.full(100, 50.0), np.full(100, -30.0)])
    loads = np.column_stack([np.full(100, 300.0), np.zeros(100)])
    both = simulate_open_loop([HIP, knee], y0, commands, loads, PERIOD)
    alone = simulate_open_loop([knee], y0[1:], commands[:, 1:], loads[:, 1:], PERIOD)
    np.testing.assert_allclose(both.states[:, 1], alone.states[:, 0], rtol=0, atol=0)


def test_many_joints_integrate_alike_on_the_kept_thread_pool_and_on_one_thread(monkeypatch):
    from concurrent.futures import ThreadPoolExecutor

    from exo_has_sim import simulate

    rng = np.random.default_rng(3)
    joints = 40  # five blocks of eight: more blocks than threads
    params = [HIP.replace(damping=d) for d in rng.uniform(500.0, 3000.0, joints)]
    y0 = np.stack([model.initial_state(p, 0.05, 300.0) for p in params])
    commands = rng.normal(0.0, 60.0, (60, joints))
    loads = np.full((60, joints), 300.0)
    monkeypatch.setenv('EXO_HAS_THREADS', '1')
    alone = simulate_open_loop(params, y0, commands, loads, PERIOD).states
    monkeypatch.setenv('EXO_HAS_THREADS', '2')
    pooled = simulate_open_loop(params, y0, commands, loads, PERIOD).states
    pool = simulate._thread_pool(2)
    again = simulate_open_loop(params, y0, commands, loads, PERIOD).states
    assert simulate._thread_pool(2) is pool  # kept, not made anew for each call
    np.testing.assert_array_equal(pooled, alone)
    np.testing.assert_array_equal(again, alone)
    # A call from one of the pool's own threads integrates there rather than wait on the pool.
    with ThreadPoolExecutor(1, thread_name_prefix=simulate._POOL_PREFIX) as inner:
        nested = inner.submit(simulate_open_loop, params, y0, commands, loads, PERIOD)
        np.testing.assert_array_equal(nested.result(timeout=60).states, alone)


@pytest.mark.parametrize('delay', [0.0, 0.0123])
def test_stepping_a_plant_matches_the_batch_simulation(delay):
    from exo_has_sim.plant_simulator import PlantSimulator

    knee = load_parameters('knee').with_effects(transport_delay=delay)
    hip = HIP.with_effects(transport_delay=delay / 2)
    params = [hip, knee]
    # Loaded, as on the rig: unloaded retraction opens vapour pockets, whose on/off switching
    # amplifies rounding differences between the two ways of cutting the steps.
    y0 = np.stack([model.initial_state(hip, 0.05, 400.0), model.initial_state(knee, 0.06, 400.0)])
    rng = np.random.default_rng(1)
    commands = rng.normal(0.0, 80.0, (400, 2))
    loads = np.full((400, 2), 400.0)
    batch = simulate_open_loop(params, y0, commands, loads, PERIOD)
    plant = PlantSimulator(params, y0)
    for k in range(400):
        state = plant.step(commands[k], loads[k], PERIOD)
    np.testing.assert_allclose(state[:, model.X], batch.states[-1, :, model.X], atol=1e-6)
    assert plant.time == pytest.approx(400 * PERIOD)
    assert plant.valve_modes() == [model.valve_mode(batch.states[-1, j], model.pack(p))
                                   for j, p in enumerate(params)]
    with pytest.raises(SimulationError, match='finite'):
        plant.step(np.array([np.nan, 0.0]), loads[0], PERIOD)


def test_a_closed_loop_transport_delay_is_applied_exactly_not_rounded_to_samples():
    period = 0.005
    middle = 0.5 * HIP.stroke  # a 10 mm step across the middle of the stroke
    x_ref = np.full(200, middle + 0.005)
    v_ref = np.zeros(200)
    loads = np.zeros(200)
    gains = np.array([[35e3, 0.0, 0.0]])
    y0 = model.initial_state(HIP, middle - 0.005)[None, :]
    results = {}
    for delay in (0.0, 0.0024, 0.0049):
        params = HIP.with_effects(transport_delay=delay)
        closed = simulate_closed_loop([params], y0, x_ref[:, None], v_ref[:, None], loads,
                                      gains, period)
        replay = simulate_open_loop([params], y0, closed.commands, loads, period)
        # The closed loop steps with ROS2, the open loop with ROS34PW2: they agree to their
        # tolerances (0.16 mm here), where a delay rounded to a sample moves it by 3 mm.
        np.testing.assert_allclose(closed.position, replay.position, atol=5e-4)
        results[delay] = closed.position[:, 0]
    # A sub-sample delay still changes the response (it was once rounded away).
    assert np.max(np.abs(results[0.0024] - results[0.0])) > 1e-4
    assert np.max(np.abs(results[0.0049] - results[0.0024])) > 1e-4

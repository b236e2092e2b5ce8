"""The model's other circuits, torque-limited motor, measured-speed input and known brake."""

import numpy as np
import pytest

from exo_has_sim import model, model_jacobian
from exo_has_sim.parameters import load_parameters
from exo_has_sim.simulate import integrate_packed, simulate_open_loop

#: The hip's HAS on a 14/8 mm cylinder of 130 mm stroke, whatever the joint's file holds: room
#: to settle at these speeds from the middle, and loads sized for its areas (the circuits'
#: physics does not depend on the joint's linkage).
HIP = load_parameters('hip').replace(stroke=0.13, bore_diameter=0.014, rod_diameter=0.008)
CHARGE = 0.5e6  # accumulator or tank pressure [Pa]
#: A rig whose brake resists both ways, so that the chamber the pump feeds carries the load.
BRAKED = {'charge_pressure': CHARGE, 'brake_force': 300.0, 'cylinder_leakage': 0.0,
          'pump_leakage': 1e-14}


def steady(params, command, load=0.0, duration=0.4, period=0.001):
    samples = round(duration / period)
    y0 = model.initial_state(params, 0.5 * params.stroke, load)
    result = simulate_open_loop([params], y0[None, :], np.full((samples, 1), command),
                                np.full(samples, load), period)
    return result.states[-1, 0]


def test_a_switched_circuit_retracts_faster_than_it_extends_by_the_area_ratio():
    params = HIP.replace(circuit='switched', **BRAKED)
    out = steady(params, 200.0)
    back = steady(params, -200.0)
    pumped = params.pump_displacement * 200.0
    assert out[model.V] == pytest.approx(pumped / params.area_a, rel=0.01)
    assert back[model.V] == pytest.approx(-pumped / params.area_b, rel=0.01)
    # The fed chamber carries the brake, the other drains to the accumulator.
    assert out[model.PA] > 5 * CHARGE and out[model.PB] == pytest.approx(CHARGE, rel=0.2)
    assert back[model.PB] > 5 * CHARGE and back[model.PA] == pytest.approx(CHARGE, rel=0.4)
    # A one-way motor: it turns forwards whichever way the valve sends its flow.
    assert back[model.N] == pytest.approx(200.0) and back[model.S] == pytest.approx(-1.0)


@pytest.mark.parametrize(('load', 'area'), [(600.0, 'area_a'), (-400.0, 'area_b')],
                         ids=['pushing in', 'pulling out'])
def test_a_closed_circuit_moves_at_the_pump_flow_over_the_loaded_chambers_area(load, area):
    params = HIP.replace(circuit='closed', charge_pressure=CHARGE, cylinder_leakage=0.0,
                         pump_leakage=1e-14)
    pumped = params.pump_displacement * 150.0
    for command in (150.0, -150.0):
        state = steady(params, command, load)
        assert state[model.V] == pytest.approx(np.sign(command) * pumped / getattr(params, area),
                                               rel=0.02)


def test_a_two_chamber_circuit_holds_the_rod_side_above_the_tank_by_the_line_drop():
    params = HIP.replace(circuit='two_chamber', charge_pressure=0.2e6)
    state = steady(params, 200.0, 500.0)
    drop = params.area_b * state[model.V] / params.return_conductance
    assert state[model.PB] == pytest.approx(0.2e6 + drop, rel=0.02)
    # The rod side's force is carried by the rodless chamber.
    balance = params.area_a * state[model.PA] - params.area_b * state[model.PB]
    assert balance == pytest.approx(500.0 + params.damping * state[model.V], rel=0.02)


def test_a_torque_limited_motor_slows_where_the_pump_needs_more_than_its_peak_torque():
    params = HIP.replace(circuit='switched', charge_pressure=CHARGE, motor_inertia=2e-5,
                         motor_torque_peak=0.5)
    held = params.motor_torque_peak * params.pump_mechanical_efficiency \
        / params.pump_displacement  # the largest pressure rise the motor can hold [Pa]
    assert steady(params, 300.0)[model.N] == pytest.approx(300.0)
    loaded = steady(params, 300.0, 1000.0)
    assert loaded[model.N] < 0.5 * 300.0
    assert loaded[model.PA] - CHARGE == pytest.approx(held, rel=0.01)
    assert steady(params, 300.0, 1500.0)[model.N] == 0.0  # stalled: a one-way pump stops


def test_the_measured_motor_speed_can_drive_the_pump_without_the_motors_lag():
    period, samples = 0.001, 100
    speeds = np.zeros((samples, 1))
    speeds[10:] = 150.0
    y0 = model.initial_state(HIP, 0.5 * HIP.stroke, 300.0)
    y0[model.N] = 0.0
    states = {}
    for speed_input in (False, True):
        packed = model.pack(HIP, speed_input=speed_input)[None, :]
        states[speed_input] = integrate_packed(packed, np.zeros(1), y0[None, :], speeds,
                                               np.full((samples, 1), 300.0), period)[:, 0]
    # The pump follows the speed at once: the pressure rises within a millisecond of the
    # step, a motor time constant (5 ms) before the lagged motor's does.
    rise = {k: int(np.argmax(s[:, model.PA] > s[0, model.PA] + 0.5e6)) for k, s in
            states.items()}
    assert rise[True] <= 12 and rise[False] >= rise[True] + 2


@pytest.mark.parametrize('circuit', ['two_chamber', 'closed', 'switched'])
def test_the_difference_jacobian_of_every_circuit_is_the_models_derivative(circuit):
    params = HIP.replace(circuit=circuit, charge_pressure=CHARGE, motor_inertia=2e-5,
                         brake_force=200.0).with_effects(entrained_air=0.01,
                                                         quadratic_leakage=2e-21)
    prm = model.pack(params)
    assert not model_jacobian.analytic(prm)
    rng = np.random.default_rng(1)
    steps = (1e-8, 1e-8, 1e-1, 1e-6, 1e-8, 1e-12, 1e-3, 1e-1)
    for _ in range(50):
        y = np.zeros(model.N_STATE)
        y[:model.N_DYNAMIC] = (rng.uniform(0.01, 0.12), rng.normal(0.0, 0.1),
                               rng.uniform(0.1e6, 10e6), rng.uniform(10.0, 300.0),
                               rng.uniform(-0.9, 0.9), 0.0, 0.0, rng.uniform(0.1e6, 10e6))
        found = np.zeros((model.N_STATE, model.N_DYNAMIC))
        model_jacobian.jacobian(y, 120.0, 100.0, prm, found)
        central = np.zeros_like(found)
        for j, step in enumerate(steps):
            plus, minus = y.copy(), y.copy()
            plus[j] += step
            minus[j] -= step
            f_plus, f_minus = np.zeros(model.N_STATE), np.zeros(model.N_STATE)
            model.rhs(plus, 120.0, 100.0, prm, f_plus)
            model.rhs(minus, 120.0, 100.0, prm, f_minus)
            central[:, j] = (f_plus - f_minus) / (2 * step)
        row_scale = np.abs(central).max(axis=1, keepdims=True) + 1e-20
        assert np.max(np.abs(found - central) / row_scale) < 1e-3

"""Checks of the second truth plant: its effects, its draws, its closed loop and its physics."""

from __future__ import annotations

import csv
import math
import time
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import second_truth_plant as sp
from numpy.testing import assert_allclose, assert_array_equal
from scipy.optimize import brentq

SEEDS = (0, 1, 2)
SHORT = 12.0  # [s] long enough for several load peaks and strides; keeps the suite fast


@cache
def _draw(seed: int, effect: str, excitation: str, size: float | None = None) -> sp.Draw:
    return sp.draw(seed, effect=effect, size=size, excitation=excitation, duration=SHORT)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _constant(value: float, count: int) -> np.ndarray:
    return np.full(count, float(value))


def _step_response(t: np.ndarray, zeta: float, wm: float) -> np.ndarray:
    """Give the unit step response of w_m^2 / (s^2 + 2 zeta w_m s + w_m^2), zeta < 1."""
    wd = wm * math.sqrt(1.0 - zeta**2)
    t = np.maximum(t, 0.0)
    decay = np.exp(-zeta * wm * t)
    return 1.0 - decay * (np.cos(wd * t) + zeta / math.sqrt(1.0 - zeta**2) * np.sin(wd * t))


@pytest.mark.parametrize('excitation', sp.EXCITATIONS)
@pytest.mark.parametrize('effect', sp.EFFECTS)
def test_every_effect_at_its_weak_end_changes_the_response_well_beyond_the_noise(
    effect: str, excitation: str
) -> None:
    for seed in SEEDS:
        twin = _draw(seed, 'none', excitation)
        hidden = _draw(seed, effect, excitation, sp.WEAKEST_SIZE[effect])
        position = _rms(hidden.clean['position'] - twin.clean['position'])
        pressure = _rms(hidden.clean['pressure_a'] - twin.clean['pressure_a'])
        ratio = max(
            position / sp.noise_std(twin.noise, 'position'),
            pressure / sp.noise_std(twin.noise, 'pressure_a'),
        )
        assert ratio > 3.0, (seed, position, pressure)


def test_a_draw_is_reproducible_from_its_seed() -> None:
    first = sp.draw(7, duration=5.0)
    second = sp.draw(7, duration=5.0)
    assert (first.effect, first.size, first.joint_type, first.excitation) == (
        second.effect,
        second.size,
        second.joint_type,
        second.excitation,
    )
    assert first.parameters == second.parameters
    assert first.noise == second.noise
    for name in sp.COLUMNS:
        assert_array_equal(first.columns[name], second.columns[name])


@pytest.mark.parametrize('seed', [3, 4, 5])
def test_forcing_a_choice_leaves_the_other_variates_of_the_seed_unchanged(seed: int) -> None:
    free = sp.draw(seed, duration=3.0)
    for effect in sp.EFFECT_CHOICES:
        forced = sp.draw(seed, effect=effect, duration=3.0)
        assert forced.effect == effect
        assert forced.parameters == free.parameters
        assert forced.plant == free.plant
        assert forced.noise == free.noise
        assert (forced.joint_type, forced.excitation) == (free.joint_type, free.excitation)
        assert forced.excitation_parameters == free.excitation_parameters
        assert_array_equal(forced.columns['reference'], free.columns['reference'])
        if effect == free.effect:
            assert forced.size == free.size
    other_joint = 'knee' if free.joint_type == 'hip' else 'hip'
    forced_joint = sp.draw(seed, other_joint, duration=3.0)
    assert (forced_joint.effect, forced_joint.size) == (free.effect, free.size)
    assert forced_joint.noise == free.noise
    other = sp.EXCITATIONS[1 - sp.EXCITATIONS.index(free.excitation)]
    forced_excitation = sp.draw(seed, excitation=other, duration=3.0)
    assert forced_excitation.parameters == free.parameters
    assert (forced_excitation.effect, forced_excitation.size) == (free.effect, free.size)


def test_drawn_nuisances_and_sizes_lie_in_their_documented_ranges() -> None:
    nominal = sp.nominal_plant('hip')
    for seed in range(12):
        result = sp.draw(seed, duration=1.0)
        assert set(result.parameters) == set(sp.NUISANCE_SPREADS)
        for name, spread in sp.NUISANCE_SPREADS.items():
            ratio = result.parameters[name] / nominal[name]
            assert 1.0 - spread <= ratio <= 1.0 + spread, name
        if result.effect == 'none':
            assert result.size == 0.0
            assert result.effects == {}
        else:
            low, high = sp.EFFECT_RANGES[result.effect]
            assert low <= result.size <= high
            assert result.effects == {result.effect: result.size}


@pytest.mark.parametrize('excitation', sp.EXCITATIONS)
def test_the_closed_loop_tracks_within_a_few_millimetres_without_an_effect(
    excitation: str,
) -> None:
    for seed in SEEDS:
        result = _draw(seed, 'none', excitation)
        settled = result.columns['time'] > 2.0
        error = result.columns['reference'] - result.columns['position']
        assert _rms(error[settled]) < 2e-3
        assert np.max(np.abs(error)) < 5e-3


@pytest.mark.parametrize('excitation', sp.EXCITATIONS)
@pytest.mark.parametrize('effect', sp.EFFECT_CHOICES)
def test_every_draw_stays_finite_in_range_and_tracking_even_at_the_strong_end(
    effect: str, excitation: str
) -> None:
    if effect == 'none':
        size = None
    else:
        low, high = sp.EFFECT_RANGES[effect]
        size = low if effect == 'relief_valve' else high
    result = _draw(0, effect, excitation, size)
    for name in sp.COLUMNS:
        assert np.all(np.isfinite(result.columns[name])), name
    for name in ('pressure_a', 'pressure_b'):
        assert result.columns[name].min() >= -0.1e6
        assert result.columns[name].max() <= 16e6
    position = result.clean['position']
    assert position.min() > 0.0
    assert position.max() < result.plant['stroke']
    error = result.columns['reference'] - result.columns['position']
    assert _rms(error[result.columns['time'] > 2.0]) < 5e-3


@pytest.mark.parametrize('excitation', sp.EXCITATIONS)
def test_the_load_peaks_always_open_the_weakest_relief_valve_and_stay_below_15_mpa(
    excitation: str,
) -> None:
    for seed in range(10):
        result = sp.draw(seed, effect='none', excitation=excitation, duration=SHORT)
        peak = result.clean['pressure_a'].max()
        assert sp.EFFECT_RANGES['relief_valve'][1] + 0.5e6 < peak < 15e6
        assert result.clean['pressure_a'].min() > 0.5e6


def test_the_measured_columns_are_the_clean_signals_plus_noise_of_the_stated_size() -> None:
    result = sp.draw(2, effect='none', excitation='sine_sum', duration=20.0)
    for name in ('pressure_a', 'pressure_b', 'motor_speed', 'load_force'):
        deviation = result.columns[name] - result.clean[name]
        assert abs(np.mean(deviation)) < 0.2 * sp.noise_std(result.noise, name)
        assert_allclose(np.std(deviation), sp.noise_std(result.noise, name), rtol=0.1)
    deviation = result.columns['position'] - result.clean['position']
    assert_allclose(np.std(deviation), sp.noise_std(result.noise, 'position'), rtol=0.1)
    quantum = result.noise['position_quantum']
    assert_allclose(result.columns['position'] / quantum,
                    np.round(result.columns['position'] / quantum), atol=1e-6)
    steps = np.diff(np.unique(result.columns['pressure_a']))
    assert_allclose(steps.min(), sp.PRESSURE_QUANTUM, rtol=1e-6)


def test_the_command_is_the_pi_law_with_feedforward_on_the_measured_position() -> None:
    result = _draw(1, 'none', 'gait')
    plant, columns = result.plant, result.columns
    error = columns['reference'] - columns['position']
    kff = plant['area_a'] / plant['pump_displacement']
    feedforward = kff * result.clean['reference_velocity']
    integral = (columns['motor_speed_command'] - feedforward - sp.KP * error) / sp.KI
    assert np.all(np.abs(columns['motor_speed_command']) < plant['motor_speed_max'])
    assert_allclose(np.diff(integral), error[:-1] * result.period, rtol=0, atol=1e-12)


def test_write_csv_writes_the_header_and_the_measured_columns_exactly(tmp_path: Path) -> None:
    result = sp.draw(4, duration=2.0)
    path = tmp_path / 'draw.csv'
    sp.write_csv(result, path)
    with path.open(newline='') as stream:
        header = next(csv.reader(stream))
    assert tuple(header) == sp.COLUMNS
    data = np.loadtxt(path, delimiter=',', skiprows=1)
    assert data.shape == (result.columns['time'].size, len(sp.COLUMNS))
    for index, name in enumerate(sp.COLUMNS):
        assert_array_equal(data[:, index], result.columns[name])
    assert_allclose(np.diff(data[:, 0]), result.period)


def _steady_state(
    plant: dict[str, float], n: float, force: float, effect: str, size: float
) -> tuple[float, float, float]:
    """Hand solution of the steady motion at motor speed n against a constant force."""
    area_a, area_b = plant['area_a'], plant['area_b']

    def pressures(v: float) -> tuple[float, float]:
        p_b = plant['tank_pressure'] + area_b * v / plant['line_conductance']
        friction = size * math.tanh(v / 1e-3) if effect == 'coulomb_friction' else 0.0
        p_a = (force + plant['damping'] * v + area_b * p_b + friction) / area_a
        return p_a, p_b

    def flow_balance(v: float) -> float:
        p_a, _ = pressures(v)
        n_eff = n - size if effect == 'pump_deadzone' else n
        flow = plant['pump_displacement'] * plant['flow_gain'] * n_eff
        flow -= plant['pump_leakage'] * p_a
        if effect == 'quadratic_leakage':
            flow -= size * p_a * abs(p_a)
        if effect == 'relief_valve' and p_a > size:
            flow -= sp.RELIEF_CRACK_CONDUCTANCE * (p_a - size)
        return flow - area_a * v

    v = brentq(flow_balance, -0.5, 0.5, xtol=1e-14)
    return (v, *pressures(v))


@pytest.mark.parametrize(
    ('effect', 'size', 'force'),
    [
        ('none', 0.0, 700.0),
        ('coulomb_friction', 120.0, 700.0),
        ('pump_deadzone', 30.0, 700.0),
        ('quadratic_leakage', 2e-20, 1500.0),
        ('relief_valve', 9e6, 1700.0),
        ('entrained_air', 0.15, 700.0),
        ('transport_delay', 0.013, 700.0),
    ],
)
def test_a_constant_motor_speed_gives_the_hand_computed_steady_velocity_and_pressures(
    effect: str, size: float, force: float
) -> None:
    plant = sp.draw(3, duration=0.1).plant
    n, count = 150.0, 161
    result = sp.simulate(
        plant,
        _constant(0.02, count),
        _constant(0.0, count),
        _constant(force, count),
        effect=effect,
        size=size,
        command=_constant(n, count),
        initial_position=0.02,
        initial_motor_speed=n,
    )
    v, p_a, p_b = _steady_state(plant, n, force, effect, size)
    if effect == 'none':  # the linear case in closed form
        area_a, area_b, leak = plant['area_a'], plant['area_b'], plant['pump_leakage']
        flow = plant['pump_displacement'] * plant['flow_gain'] * n
        flow -= leak * (force + area_b * plant['tank_pressure']) / area_a
        resistance = plant['damping'] + area_b**2 / plant['line_conductance']
        assert_allclose(v, flow / (area_a + leak * resistance / area_a), rtol=1e-12)
    assert_allclose(result['velocity'][-1], v, rtol=1e-4)
    assert_allclose(result['pressure_a'][-1], p_a, rtol=1e-4)
    assert_allclose(result['pressure_b'][-1], p_b, rtol=1e-4)
    assert_allclose(np.diff(result['position'][-21:]) / sp.PERIOD, v, rtol=1e-4)


@pytest.mark.parametrize('effect', ['none', 'pump_deadzone', 'quadratic_leakage'])
def test_holding_a_constant_load_settles_at_the_static_pressure_and_the_leakage_speed(
    effect: str,
) -> None:
    plant = sp.draw(8, duration=0.1).plant
    count = 1201
    load = np.where(np.arange(count) < 100, 400.0, 1600.0)
    size = {'none': 0.0, 'pump_deadzone': 20.0, 'quadratic_leakage': 2e-20}[effect]
    result = sp.simulate(
        plant, _constant(0.06, count), _constant(0.0, count), load, effect=effect, size=size
    )
    area_a, area_b = plant['area_a'], plant['area_b']
    p_a = (1600.0 + area_b * plant['tank_pressure']) / area_a
    assert_allclose(result['pressure_a'][-1], p_a, rtol=1e-5)
    assert_allclose(result['pressure_b'][-1], plant['tank_pressure'], rtol=1e-6)
    leak = plant['pump_leakage'] * p_a + (size * p_a**2 if effect == 'quadratic_leakage' else 0)
    n = leak / (plant['pump_displacement'] * plant['flow_gain'])
    n += size if effect == 'pump_deadzone' else 0.0
    assert_allclose(result['motor_speed'][-1], n, rtol=1e-4)
    assert_allclose(result['position'][-1], 0.06, atol=2e-6)
    # The load step moved the piston before the integral took it back.
    assert np.min(result['position']) < 0.06 - 1e-4


@pytest.mark.parametrize('seed', [0, 5])
def test_the_motor_loop_follows_the_second_order_step_response_and_its_overshoot(
    seed: int,
) -> None:
    plant = sp.draw(seed, duration=0.1).plant
    zeta, wm = plant['motor_damping_ratio'], plant['motor_natural_frequency']
    assert 0.6 <= zeta <= 0.9
    assert_allclose(wm, 2.0 * zeta / plant['motor_time_constant'])
    count, step = 41, 100.0
    result = sp.simulate(
        plant,
        _constant(0.05, count),
        _constant(0.0, count),
        _constant(500.0, count),
        command=_constant(step, count),
        initial_motor_speed=0.0,
    )
    t = result['time']
    assert_allclose(result['motor_speed'], step * _step_response(t, zeta, wm), atol=1e-6 * step)
    overshoot = math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta**2))
    t_peak = math.pi / (wm * math.sqrt(1.0 - zeta**2))
    assert_allclose(_step_response(np.array([t_peak]), zeta, wm)[0], 1.0 + overshoot)
    # The samples around the peak bracket it from below.
    assert result['motor_speed'].max() <= step * (1.0 + overshoot) + 1e-9
    assert result['motor_speed'].max() > step * (1.0 + 0.5 * overshoot)


@pytest.mark.parametrize('delay', [0.002, 0.0073, 0.0185])
def test_the_transport_delay_shifts_the_motor_response_by_exactly_its_length(
    delay: float,
) -> None:
    plant = sp.draw(2, duration=0.1).plant
    zeta, wm = plant['motor_damping_ratio'], plant['motor_natural_frequency']
    count, step, start = 61, 80.0, 10
    command = np.where(np.arange(count) >= start, step, 0.0)
    result = sp.simulate(
        plant,
        _constant(0.05, count),
        _constant(0.0, count),
        _constant(500.0, count),
        effect='transport_delay',
        size=delay,
        command=command,
        initial_motor_speed=0.0,
    )
    expected = step * _step_response(result['time'] - start * sp.PERIOD - delay, zeta, wm)
    assert_allclose(result['motor_speed'], expected, atol=1e-5 * step)


def test_the_motor_speed_saturates_at_the_limit_of_the_parameters_file() -> None:
    plant = sp.draw(1, duration=0.1).plant
    count = 41
    result = sp.simulate(
        plant,
        _constant(0.01, count),
        _constant(0.0, count),
        _constant(500.0, count),
        command=_constant(1000.0, count),
        initial_motor_speed=0.0,
    )
    assert result['motor_speed'].max() <= plant['motor_speed_max']
    assert_allclose(result['motor_speed'][-10:], plant['motor_speed_max'])


def test_free_air_lowers_the_bulk_modulus_at_low_pressure_only() -> None:
    modulus = 1.2e9
    assert sp.effective_bulk_modulus(5e6, modulus, 0.0) == modulus
    # At atmospheric pressure the air dominates: E_eff ~ 1.4 p_atm / alpha0.
    at_atmosphere = sp.effective_bulk_modulus(0.0, modulus, 0.1)
    hand = 1.0 / (0.9 / modulus + 0.1 / (1.4 * 101325.0))
    assert_allclose(at_atmosphere, hand, rtol=1e-12)
    assert_allclose(at_atmosphere, 1.4 * 101325.0 / 0.1, rtol=0.01)
    # At 10 MPa the air is compressed to 0.1 * 0.0101325^(1 / 1.4) of the volume.
    p_abs = 10e6 + 101325.0
    air = 0.1 * (101325.0 / p_abs) ** (1.0 / 1.4)
    hand = (0.9 + air) / (0.9 / modulus + air / (1.4 * p_abs))
    assert_allclose(sp.effective_bulk_modulus(10e6, modulus, 0.1), hand, rtol=1e-12)
    assert 0.5 * modulus < hand < modulus


def test_a_30_s_draw_reports_its_simulation_time() -> None:
    start = time.perf_counter()
    result = sp.draw(21, duration=30.0)
    elapsed = time.perf_counter() - start
    print(f'30 s draw ({result.effect}, {result.excitation}) simulated in {elapsed:.3f} s')
    assert result.columns['time'][-1] == pytest.approx(30.0)

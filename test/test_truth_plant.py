"""Tests of the independent truth plant and its seeded data generator (test/truth_plant.py).

The references are analytic where the physics allows: steady velocities and pressures from the
flow and force balances, the motor's first-order step response, the mixture's modulus from
its volume, the hydraulic mode's frequency from the linearised plant.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import truth_plant as tp
from numpy.testing import assert_allclose

PERIOD = 1.0 / tp.SAMPLE_RATE
LOAD = 1000.0  # N, 6.5 MPa on the rodless area
# Largest noise std drawn: the bar an effect must clear.
TOP_NOISE = {name: high for name, (_, high) in tp.NOISE_RANGES.items()}
ALL_EFFECTS = {'coulomb_friction': 60.0, 'pump_deadzone': 8.0, 'transport_delay': 0.0063,
               'quadratic_leakage': 1e-20, 'relief_valve': 9e6, 'entrained_air': 0.02}


@pytest.fixture(scope='module')
def hip() -> tp.HasParameters:
    return tp.nominal_parameters('hip')


def steady_velocity(params: tp.HasParameters, command: float, load: float,
                    effects: dict[str, float] | None = None) -> tuple[float, float]:
    """Steady extension velocity [m/s] and pressure [Pa] at a constant command, engaged.

    Flow balance ``D_p n_pump = A_A v + L_n p + L_n2 p^2 + G_crack (p - p_crack)^+`` with the
    force balance ``A_A p = F + B v + F_c`` (v >> 1 mm/s), solved by fixed-point iteration.
    """
    e = effects or {}
    n_pump = command - e.get('pump_deadzone', 0.0)
    v = 0.0
    for _ in range(200):
        p = (load + params.damping * v + e.get('coulomb_friction', 0.0)) / params.area_a
        leak = params.pump_leakage * p + e.get('quadratic_leakage', 0.0) * p * p
        if 'relief_valve' in e:
            leak += tp.RELIEF_CRACK_CONDUCTANCE * max(p - e['relief_valve'], 0.0)
        v = (params.pump_displacement * n_pump - leak) / params.flow_area
    return v, p


def run_open_loop(params: tp.HasParameters, effects: dict[str, float], command: float,
                  load: float = LOAD, duration: float = 1.2) -> tp.Simulation:
    # 1.2 s: the hydraulic mode's ringing (damping ratio about 0.1) has decayed to 1e-9.
    samples = round(duration / PERIOD)
    return tp.simulate(params, effects, command=np.full(samples, command), load_force=load,
                       initial_position=0.02)


def test_steady_extension_velocity_is_k_n_times_the_volumetric_efficiency(hip):
    command = 100.0
    result = run_open_loop(hip, {}, command)
    pressure = (LOAD + hip.damping * result.velocity[-1]) / hip.area_a
    efficiency = 1.0 - hip.pump_leakage * pressure / (hip.pump_displacement * command)
    k = hip.pump_displacement / hip.flow_area
    assert_allclose(result.velocity[-20:], k * command * efficiency, rtol=1e-6)
    assert_allclose(result.clean['pressure_a'][-20:], pressure, rtol=1e-6)
    # Eq. 14 (K with leakage and damping, A_A for the paper's averaged area) gives the same
    # velocity without load.
    unloaded = run_open_loop(hip, {}, command, load=0.0)
    eq14 = hip.pump_displacement * hip.area_a / (
        hip.pump_leakage * hip.damping + hip.area_a * hip.area_a)
    assert_allclose(unloaded.velocity[-1], eq14 * command, rtol=1e-6)


def test_static_pressure_is_load_over_rodless_area_at_rest(hip):
    # Start 10 mm below the reference: the PD lifts the load and settles where the motor
    # replaces the leakage, the error being that speed over kp (no integral action).
    samples = round(3.0 / PERIOD)
    result = tp.simulate(hip, {}, reference=np.full(samples, 0.06), load_force=LOAD,
                         initial_position=0.05)
    pressure = LOAD / hip.area_a
    holding = hip.pump_leakage * pressure / hip.pump_displacement
    assert_allclose(result.clean['pressure_a'][-1], pressure, rtol=1e-6)
    assert_allclose(result.clean['motor_speed'][-1], holding, rtol=1e-5)
    assert_allclose(0.06 - result.clean['position'][-1], holding / tp.KP, rtol=1e-4)
    assert abs(result.velocity[-1]) < 1e-8


@pytest.mark.parametrize('effect', ['coulomb_friction', 'pump_deadzone', 'quadratic_leakage',
                                    'relief_valve'])
def test_each_steady_state_effect_has_the_size_its_definition_gives(hip, effect):
    effects = {effect: ALL_EFFECTS[effect]}
    load = 1800.0  # 11.7 MPa, above the crack pressure
    result = run_open_loop(hip, effects, 120.0, load=load)
    velocity, pressure = steady_velocity(hip, 120.0, load, effects)
    assert_allclose(result.velocity[-20:], velocity, rtol=1e-6)
    assert_allclose(result.clean['pressure_a'][-20:], pressure, rtol=1e-6)
    plain, _ = steady_velocity(hip, 120.0, load)
    assert abs(velocity - plain) > 0.005 * plain  # the check is not blind to the effect


def test_transport_delay_holds_the_motor_back_by_exactly_the_delay(hip):
    delay = 0.0063  # not a multiple of the sample or the integration step
    command = np.r_[np.zeros(10), np.full(30, 100.0)]
    result = tp.simulate(hip, {'transport_delay': delay}, command=command, load_force=LOAD)
    start = result.clean['motor_speed'][0]  # holding speed, commanded before t = 0 as well
    tau = hip.motor_time_constant
    t = result.clean['time']
    # The zeros sent from t = 0 act from the delay on, the step sent at 10 periods likewise.
    after_zero = start * np.exp(-np.clip(t - delay, 0.0, None) / tau)
    at_step = start * math.exp(-10 * PERIOD / tau)
    after_step = 100.0 + (at_step - 100.0) * np.exp(-np.clip(t - 10 * PERIOD - delay, 0.0,
                                                             None) / tau)
    expected = np.where(t < 10 * PERIOD + delay, after_zero, after_step)
    assert_allclose(result.clean['motor_speed'], expected, atol=1e-6)


def test_mixture_modulus_is_minus_v_dp_dv_of_oil_and_polytropic_air():
    oil, air = 1.2e9, 0.03
    p0 = tp.ATMOSPHERIC_PRESSURE

    def volume(p: float) -> float:
        oil_volume = (1.0 - air) * math.exp(-p / oil)
        return oil_volume + air * (p0 / (p + p0)) ** (1.0 / tp.AIR_POLYTROPIC_EXPONENT)

    for p in (0.0, 3e5, 1e6, 5e6, 1.4e7):
        dp = 1.0
        slope = (volume(p + dp) - volume(p - dp)) / (2 * dp)
        assert_allclose(tp.mixture_bulk_modulus(p, oil, air), -volume(p) / slope, rtol=1e-6)
    assert tp.mixture_bulk_modulus(1e6, oil, 0.0) == oil
    assert tp.mixture_bulk_modulus(1e6, oil, air) < 0.5 * oil  # air matters at 1 MPa


def test_entrained_air_lowers_the_hydraulic_mode_as_the_mixture_modulus_predicts(hip):
    # A 10 N load step at 2 MPa rings the load on the oil spring; its damped frequency is the
    # imaginary part of the eigenvalues of the linearised (v, p) dynamics with E_eff(p).
    period, samples, x0, p0 = 2e-4, 1000, 0.065, 2e6
    load = np.full(samples, p0 * hip.area_a + 10.0)
    for air in (0.0, 0.02):
        effects = {'entrained_air': air} if air else {}
        holding = tp.holding_speed(hip, effects, p0)  # the valve stays engaged
        result = tp.simulate(hip, effects, command=np.full(samples, holding), load_force=load,
                             period=period, initial_state=[x0, 0.0, p0, holding, 1.0, 0.0],
                             substeps=4)
        pressure = result.clean['pressure_a'] - load[0] / hip.area_a
        up = np.flatnonzero((pressure[:-1] < 0.0) & (pressure[1:] >= 0.0))
        # Interpolated upward zero crossings over the first cycles.
        times = (up + pressure[up] / (pressure[up] - pressure[up + 1])) * period
        assert times.size >= 4
        measured = 2 * math.pi / np.mean(np.diff(times[:4]))
        capacitance = (hip.dead_volume + hip.area_a * x0) / tp.mixture_bulk_modulus(
            p0, hip.bulk_modulus, air)
        system = np.array([[-hip.damping / hip.moving_mass, hip.area_a / hip.moving_mass],
                           [-hip.flow_area / capacitance, -hip.pump_leakage / capacitance]])
        expected = np.abs(np.linalg.eigvals(system).imag).max()
        assert_allclose(measured, expected, rtol=0.02)


def valve_cycle(peak_load: float = 2900.0) -> dict[str, np.ndarray | float]:
    """Open-loop inputs of the knee through every valve mode, 2.5 s.

    0-1.2 s: two motor reversals under a 700-1900 N load (valve held in assist); 1.2-1.5 s:
    motor stopped, load removed (the chamber cavitates as the oil spring relaxes, the valve
    falls to free mode); 1.5-2.5 s: the motor extends at 80 rad/s (the valve re-engages) under a
    raised-cosine load to ``peak_load`` (2900 N: 18.8 MPa static, past the relief setting).
    """
    t = np.arange(500) * PERIOD
    command = np.where(t < 1.2, 60.0 * np.cos(2 * math.pi * t) + 10.0,
                       np.where(t < 1.5, 0.0, 80.0))
    load = np.where(t < 1.2, 700.0 + 1200.0 * (0.5 - 0.5 * np.cos(math.pi * t)),
                    np.where(t < 1.5, 0.0,
                             peak_load * (0.5 - 0.5 * np.cos(2 * math.pi * (t - 1.5)))))
    return {'command': command, 'load_force': load, 'initial_position': 0.06}


def test_the_spool_target_is_the_larger_of_the_speed_and_inlet_pressure_smoothsteps(hip):
    def smoothstep(z: float) -> float:
        z = min(max(z, 0.0), 1.0)
        return 3 * z**2 - 2 * z**3

    for n in (0.0, 0.3, -0.9, 1.25, -1.7, 2.5, -300.0):
        for p in (-9e4, 0.0, 0.25e6, 0.35e6, 0.45e6, 1e6, 1.4e7):
            for s in (0.0, 0.3, 0.8, 1.0):
                by_speed = smoothstep((abs(n) - hip.valve_release_speed)
                                      / (hip.valve_engage_speed - hip.valve_release_speed))
                by_pressure = smoothstep((s * p - hip.valve_drop_pressure)
                                         / (hip.valve_hold_pressure - hip.valve_drop_pressure))
                assert_allclose(tp.spool_target(hip, n, p, s), max(by_speed, by_pressure),
                                rtol=1e-12, atol=1e-15)
    # The midpoints of both bands, and a free valve does not see the chamber.
    assert tp.spool_target(hip, 1.25, 0.0, 0.0) == pytest.approx(0.5, abs=1e-12)
    assert tp.spool_target(hip, 0.0, 0.35e6, 1.0) == pytest.approx(0.5, abs=1e-12)
    assert tp.spool_target(hip, 0.0, 1.4e7, 0.0) == 0.0


def test_a_loaded_valve_holds_through_reversals_and_frees_only_unloaded_at_rest():
    params = tp.nominal_parameters('knee')
    result = tp.simulate(params, {}, **valve_cycle())
    t, n = result.clean['time'], result.clean['motor_speed']
    loaded = t < 1.2
    assert np.count_nonzero(np.diff(np.sign(n[loaded])) != 0) == 2  # two reversals
    assert result.spool[loaded].min() > 1.0 - 1e-9
    assert result.clean['pressure_a'][loaded].min() > 4.0 * params.valve_hold_pressure
    # Stopped and unloaded: the spool falls to free within the stop, the motor brings it back.
    assert result.spool[(t > 1.4) & (t < 1.5)].max() < 1e-6
    assert result.spool[t > 1.6].min() > 1.0 - 1e-6


def test_halving_the_step_changes_an_open_loop_run_by_far_less_than_the_noise():
    # Through motor reversals under load, a free-mode stop with cavitation, re-engagement and a
    # relief opening, then with all effects (the crack pressure instead of the relief).
    params = tp.nominal_parameters('knee')
    for effects, peak_load in (({}, 2900.0), (ALL_EFFECTS, 2000.0)):
        inputs = valve_cycle(peak_load)
        coarse, fine, finer = (
            tp.simulate(params, effects, substeps=n * tp.SUBSTEPS,
                        stiff_limit=tp.STIFF_LIMIT / n, **inputs) for n in (1, 2, 4))
        pressure = fine.clean['pressure_a']
        if effects:
            assert pressure.max() > effects['relief_valve'] + 1e6
        else:
            assert pressure.max() > params.relief_pressure  # the relief opens
            assert pressure.min() == params.cavitation_pressure  # a vapour pocket opens
        assert fine.spool.min() < 1e-6 and fine.spool[-1] > 1.0 - 1e-6
        assert np.ptp(fine.clean['motor_speed']) > 100.0
        for name, noise in (('position', 'position'), ('pressure_a', 'pressure'),
                            ('motor_speed', 'motor_speed')):
            low = tp.NOISE_RANGES[noise][0]
            assert_allclose(coarse.clean[name], fine.clean[name], rtol=0, atol=0.1 * low)
            assert_allclose(fine.clean[name], finer.clean[name], rtol=0, atol=0.1 * low)


def test_halving_the_step_changes_a_closed_loop_sine_sum_draw_by_far_less_than_the_noise():
    # The draw's plant, reference and load under the truth plant's PD loop, without and with
    # all effects. Measured: under 1e-7 (none) and 4e-4 (all effects) of the smallest noise.
    d = tp.draw(0, effect='none', excitation='sine_sum')
    params = tp.plant_parameters(d)
    for effects in ({}, ALL_EFFECTS):
        coarse, fine, finer = (
            tp.simulate(params, effects, reference=d.clean['reference'],
                        load_force=d.clean['load_force'], substeps=n * tp.SUBSTEPS,
                        stiff_limit=tp.STIFF_LIMIT / n).clean for n in (1, 2, 4))
        for name, noise in (('position', 'position'), ('pressure_a', 'pressure'),
                            ('motor_speed', 'motor_speed')):
            low = tp.NOISE_RANGES[noise][0]
            assert_allclose(coarse[name], fine[name], rtol=0, atol=0.01 * low)
            assert_allclose(fine[name], finer[name], rtol=0, atol=0.01 * low)


def test_effect_free_draws_keep_the_loaded_chamber_from_collapsing():
    # A collapse: the chamber pressure falls under the valve's drop pressure while the load is
    # on (as it did at motor reversals with a spool that followed the motor speed alone, 19-92
    # times in every 20 s draw). Near the reversals (motor slower than twice the engage
    # speed) it stays above the hold pressure, so the spool cannot leave its seat there.
    for excitation in tp.EXCITATIONS:
        for seed in range(5):
            d = tp.draw(seed, effect='none', excitation=excitation)
            params = tp.plant_parameters(d)
            pressure, motor_speed = d.clean['pressure_a'], d.clean['motor_speed']
            low = (pressure < params.valve_drop_pressure) & (d.clean['load_force'] > 0.0)
            collapses = np.count_nonzero(low[1:] & ~low[:-1]) + int(low[0])
            assert collapses == 0, (excitation, seed, pressure.min())
            slow = np.abs(motor_speed) < 2.0 * params.valve_engage_speed
            assert np.count_nonzero(np.diff(np.sign(motor_speed)) != 0) >= 4
            assert pressure[slow].min() > 2.0 * params.valve_hold_pressure, (excitation, seed)


def test_a_draw_is_reproducible_from_its_seed():
    first, second = tp.draw(11, duration=2.0), tp.draw(11, duration=2.0)
    assert (first.effect, first.size, first.excitation) == (second.effect, second.size,
                                                            second.excitation)
    assert first.parameters == second.parameters and first.noise == second.noise
    for name in tp.COLUMNS:
        np.testing.assert_array_equal(first.columns[name], second.columns[name])
    other = tp.draw(12, duration=2.0)
    assert not np.array_equal(first.columns['position'], other.columns['position'])


def test_forcing_the_effect_leaves_every_other_draw_of_the_seed_unchanged():
    free = tp.draw(5, duration=2.0)
    for effect in tp.EFFECT_CHOICES:
        forced = tp.draw(5, effect=effect, duration=2.0)
        assert forced.effect == effect
        assert (forced.joint_type, forced.excitation, forced.parameters, forced.noise,
                forced.load) == (free.joint_type, free.excitation, free.parameters, free.noise,
                                 free.load)
        np.testing.assert_array_equal(forced.columns['reference'], free.columns['reference'])
        np.testing.assert_array_equal(forced.columns['load_force'], free.columns['load_force'])
    assert tp.draw(5, effect='none', size=3.0, duration=0.1).size == 0.0
    assert tp.draw(5, effect='pump_deadzone', size=3.0, duration=0.1).size == 3.0


def test_draws_cover_every_choice_within_the_documented_ranges():
    draws = [tp.draw(seed, duration=0.05) for seed in range(120)]
    assert {d.effect for d in draws} == set(tp.EFFECT_CHOICES)
    assert {d.excitation for d in draws} == set(tp.EXCITATIONS)
    assert {d.joint_type for d in draws} == set(tp.JOINT_TYPES)
    for d in draws:
        if d.effect == 'none':
            assert d.size == 0.0
        else:
            low, high, _ = tp.EFFECT_RANGES[d.effect]
            assert low <= d.size <= high
        nominal = tp.nominal_parameters(d.joint_type)
        for name in tp.DRAWN_PARAMETERS:
            ratio = d.parameters[name] / getattr(nominal, name)
            assert 1 - tp.PARAMETER_SPREAD <= ratio <= 1 + tp.PARAMETER_SPREAD
        for name, (low, high) in tp.NOISE_RANGES.items():
            assert low <= d.noise[name] <= high
        assert d.load_mass == 50.0 and d.period == PERIOD


@pytest.mark.parametrize('excitation', tp.EXCITATIONS)
def test_columns_are_finite_sampled_at_200_hz_and_within_the_stroke(excitation):
    d = tp.draw(3, excitation=excitation)
    assert tuple(d.columns) == tp.COLUMNS
    samples = round(20.0 * tp.SAMPLE_RATE)
    for name in tp.COLUMNS:
        assert d.columns[name].shape == (samples,)
        assert np.all(np.isfinite(d.columns[name]))
    assert_allclose(np.diff(d.columns['time']), PERIOD, rtol=1e-9)
    stroke = tp.plant_parameters(d).stroke
    # The end stops give way by their load over their stiffness, a fraction of a millimetre.
    assert -1e-3 < d.clean['position'].min() and d.clean['position'].max() < stroke + 1e-3
    margin = 0.01
    assert margin < d.columns['reference'].min() and d.columns['reference'].max() < stroke - margin
    assert np.abs(d.columns['motor_speed_command']).max() <= tp.nominal_parameters(
        d.joint_type).motor_speed_max
    assert_allclose(np.std(d.columns['pressure_b']), d.noise['pressure'], rtol=0.1)
    assert_allclose(np.std(d.columns['position'] - d.clean['position']), d.noise['position'],
                    rtol=0.1)
    # The load keeps the chamber loaded: its floor is the drawn low static pressure.
    assert_allclose(d.clean['load_force'].min() / tp.nominal_parameters('hip').area_a,
                    d.load['pressure_low'], rtol=0.05)


def test_a_twenty_second_draw_generates_in_well_under_a_second():
    tp.draw(1, duration=0.1)  # compiled (or loaded from the cache) outside the timing
    elapsed = min(_time_draw(seed) for seed in (1, 2))
    assert elapsed < 1.0


def _time_draw(seed: int) -> float:
    start = time.perf_counter()
    tp.draw(seed, excitation='walk')
    return time.perf_counter() - start


def test_relief_draws_cross_the_crack_pressure_in_every_load_cycle():
    crack = tp.EFFECT_RANGES['relief_valve'][1]  # the highest crack pressure drawn
    for seed, excitation in enumerate(tp.EXCITATIONS):
        d = tp.draw(seed, effect='relief_valve', size=crack, excitation=excitation)
        above = d.clean['pressure_a'] > crack
        load_above = d.clean['load_force'] / tp.plant_parameters(d).area_a > crack
        crossings = np.count_nonzero(above[1:] & ~above[:-1])
        cycles = np.count_nonzero(load_above[1:] & ~load_above[:-1])
        # The slowest load (sine sum, 0.1-0.25 Hz) still passes the crack twice in 20 s.
        assert cycles >= 2 and crossings >= cycles, (excitation, crossings, cycles)
        assert np.mean(above) > 0.1


def replay_residual(d: tp.Draw, window: float = 1.0,
                    effects: dict[str, float] | None = None) -> dict[str, float]:
    """RMS difference [SI] between a draw's noise-free columns and a replay of its commands.

    The replay runs the draw's plant with ``effects`` (none by default) open loop on the
    recorded commands and loads, restarted from the true state at every window: what a model
    that lacks the effect cannot explain, without the closed loop's correction of it.
    """
    params = tp.plant_parameters(d)
    truth = tp.simulate(params, d.effects, reference=d.clean['reference'],
                        load_force=d.clean['load_force'])
    commands = truth.clean['motor_speed_command']
    size = round(window / PERIOD)
    residual: dict[str, list[np.ndarray]] = {'position': [], 'pressure_a': [],
                                             'motor_speed': []}
    for start in range(0, commands.size - size + 1, size):
        part = slice(start, start + size)
        replay = tp.simulate(params, effects or {}, command=commands[part],
                             load_force=truth.clean['load_force'][part],
                             initial_state=truth.states[start],
                             past_commands=commands[max(start - 20, 0):start])
        for name, values in residual.items():
            values.append(truth.clean[name][part] - replay.clean[name])
    return {name: float(np.sqrt(np.mean(np.concatenate(v) ** 2)))
            for name, v in residual.items()}


def test_a_replay_with_the_true_effect_reproduces_the_draw_exactly():
    d = tp.draw(4, effect='transport_delay', excitation='squat', duration=4.0)
    residual = replay_residual(d, effects=d.effects)
    assert residual['position'] < 1e-12 and residual['motor_speed'] < 1e-9


@pytest.mark.parametrize('effect', tp.EFFECTS)
def test_each_effect_at_its_weak_end_shows_clearly_above_the_noise(effect):
    # The weak end: the smallest size, or for the relief valve the highest crack pressure.
    weak = tp.effect_size(effect, 1.0 if effect == 'relief_valve' else 0.0)
    for seed, excitation in enumerate(tp.EXCITATIONS):
        d = tp.draw(seed, effect=effect, size=weak, excitation=excitation, duration=8.0)
        residual = replay_residual(d)
        clearance = max(residual['position'] / TOP_NOISE['position'],
                        residual['pressure_a'] / TOP_NOISE['pressure'],
                        residual['motor_speed'] / TOP_NOISE['motor_speed'])
        assert clearance > 3.0, (excitation, residual)
        # And in closed loop, effect on against off on the same draw.
        twin = tp.draw(seed, effect='none', excitation=excitation, duration=8.0)
        closed = max(
            np.sqrt(np.mean((d.clean['position'] - twin.clean['position']) ** 2))
            / TOP_NOISE['position'],
            np.sqrt(np.mean((d.clean['pressure_a'] - twin.clean['pressure_a']) ** 2))
            / TOP_NOISE['pressure'])
        assert closed > 1.0, (excitation, closed)


def test_write_csv_writes_the_header_and_every_sample_exactly(tmp_path: Path):
    d = tp.draw(8, duration=1.0)
    path = tmp_path / 'draw.csv'
    tp.write_csv(d, path)
    lines = path.read_text().splitlines()
    assert lines[0] == ','.join(tp.COLUMNS)
    assert len(lines) == 1 + d.columns['time'].size
    table = np.loadtxt(path, delimiter=',', skiprows=1)
    for index, name in enumerate(tp.COLUMNS):
        np.testing.assert_array_equal(table[:, index], d.columns[name])


def test_invalid_effects_are_refused(hip):
    with pytest.raises(ValueError, match='unknown effect'):
        tp.simulate(hip, {'stiction': 1.0}, command=np.zeros(2))
    with pytest.raises(ValueError, match='below relief_pressure'):
        tp.simulate(hip, {'relief_valve': hip.relief_pressure}, command=np.zeros(2))
    with pytest.raises(ValueError, match='not negative'):
        tp.simulate(hip, {'coulomb_friction': -1.0}, command=np.zeros(2))
    with pytest.raises(ValueError, match='effect must be one of'):
        tp.draw(0, effect='backlash', duration=0.1)

"""Tests of the third truth plant: determinism, twins, oil balance, physics and the interface."""

from __future__ import annotations

import csv
import functools
import math
import time

import numpy as np
import pytest
import third_truth_plant as tp

# Each measured channel and the noise level it is judged against.
NOISY_CHANNELS = {'position': 'position', 'pressure_a': 'pressure', 'pressure_b': 'pressure',
                  'motor_speed': 'motor_speed', 'load_force': 'load_force'}


@functools.cache
def record(seed: int, **kwargs: object) -> tp.Draw:
    """Return a record, simulated once per test session."""
    return tp.draw(seed, **kwargs)


def excess_over_noise(changed: tp.Draw, base: tp.Draw) -> float:
    """Return the largest RMS change of a measured channel, in that channel's noise levels."""
    return max(
        float(np.sqrt(np.mean((changed.columns[ch] - base.columns[ch]) ** 2)))
        / base.noise[level]
        for ch, level in NOISY_CHANNELS.items())


def open_loop(plant: dict[str, float], commands: np.ndarray, rate: float,
              substeps: int | None = None) -> dict[str, np.ndarray]:
    """Run the rig on signed motor speed commands, at mid stroke, without its controller."""
    n = commands.size
    return tp.run(plant, np.full(n, tp.MID_STROKE), np.zeros(n), commands=commands, rate=rate,
                  substeps=substeps)


def test_the_interface_has_the_agreed_names_and_units():
    assert tp.EFFECT_CHOICES == ('none', *tp.EFFECTS)
    assert set(tp.EFFECT_RANGES) == set(tp.EFFECTS)
    assert all(low < high for low, high in tp.EFFECT_RANGES.values())
    d = record(1, duration=2.0)
    assert set(d.columns) == set(tp.COLUMNS)
    assert d.joint_type == 'hip'
    assert d.effect in tp.EFFECT_CHOICES and d.excitation in tp.EXCITATIONS
    assert d.effects == ({} if d.effect == 'none' else {d.effect: d.size})
    assert np.allclose(np.diff(d.columns['time']), 1.0 / tp.RATE)
    assert d.period == pytest.approx(1.0 / tp.RATE)
    for key in ('position', 'velocity', 'pressure_a', 'pressure_b', 'pressure_accumulator',
                'motor_speed', 'spool', 'brake_force', 'pump_flow'):
        assert d.clean[key].shape == d.columns['time'].shape
    sheet = tp.datasheet()
    assert sheet['bore_diameter'] == 0.05 and sheet['rod_diameter'] == 0.028
    assert sheet['pump_displacement'] == pytest.approx(1.6e-6 / (2 * math.pi))


def test_the_same_seed_gives_the_same_record():
    a = tp.draw(5, duration=3.0)
    b = tp.draw(5, duration=3.0)
    assert (a.effect, a.size, a.excitation) == (b.effect, b.size, b.excitation)
    assert a.parameters == b.parameters and a.noise == b.noise and a.plant == b.plant
    for name in tp.COLUMNS:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    for name in a.clean:
        np.testing.assert_array_equal(a.clean[name], b.clean[name])


def test_forcing_one_choice_leaves_the_rig_the_excitation_and_the_noise_unchanged():
    base = record(7, duration=3.0)
    other_effect = next(e for e in tp.EFFECTS if e != base.effect)
    twin = tp.draw(7, effect=other_effect, duration=3.0)
    assert twin.effect == other_effect and twin.effects == {other_effect: twin.size}
    assert twin.parameters == base.parameters and twin.noise == base.noise
    assert twin.excitation == base.excitation
    assert twin.excitation_parameters == base.excitation_parameters
    np.testing.assert_array_equal(twin.columns['reference'], base.columns['reference'])

    def noise(d: tp.Draw) -> np.ndarray:
        # The speed encoder's noise is additive and unquantised, so it shows exactly.
        return d.columns['motor_speed'] - d.clean['side'] * d.clean['motor_speed']

    np.testing.assert_allclose(noise(twin), noise(base), atol=1e-9)

    other_excitation = next(e for e in tp.EXCITATIONS if e != base.excitation)
    swapped = tp.draw(7, excitation=other_excitation, duration=3.0)
    assert swapped.effect == base.effect and swapped.size == base.size
    assert swapped.parameters == base.parameters
    np.testing.assert_allclose(noise(swapped), noise(base), atol=1e-9)

    braked = tp.draw(7, brake_force=6500.0, duration=3.0)
    assert braked.parameters['brake_force'] == 6500.0
    assert {k: v for k, v in braked.parameters.items() if k != 'brake_force'} == {
        k: v for k, v in base.parameters.items() if k != 'brake_force'}
    assert braked.effect == base.effect and braked.excitation == base.excitation


@pytest.mark.parametrize('effect', ['relief_valve', 'entrained_air'])
def test_oil_is_conserved_and_each_chamber_holds_what_flowed_into_it(effect):
    d = record(11, effect=effect, brake_force=7000.0, duration=8.0)
    c = d.clean
    if effect == 'relief_valve':
        assert c['volume_relief'][-1] - c['volume_relief'][0] > 1e-6  # the path is exercised

    def change(name: str) -> np.ndarray:
        return c[name] - c[name][0]

    scale = d.plant['accumulator_volume']
    total = change('oil_a') + change('oil_b') + change('oil_pump') + change('oil_accumulator')
    assert np.max(np.abs(total)) < 1e-10 * scale
    into_a = change('volume_pump_to_a') - change('volume_a_to_accumulator')
    into_a -= change('volume_piston_leakage')
    into_b = change('volume_pump_to_b') - change('volume_b_to_accumulator')
    into_b += change('volume_piston_leakage')
    into_pump = change('volume_pump') - change('volume_pump_to_a') - change('volume_pump_to_b')
    into_pump -= change('volume_relief')
    for held, flowed in ((change('oil_a'), into_a), (change('oil_b'), into_b),
                         (change('oil_pump'), into_pump)):
        assert np.max(np.abs(held - flowed)) < 1e-9 * scale
    # The sampled pump flow, integrated, gives the pumped volume (sampling error only).
    pumped = np.concatenate([[0.0], np.cumsum(0.5 * (c['pump_flow'][1:] + c['pump_flow'][:-1])
                                              * d.period)])
    moved = np.sum(np.abs(c['pump_flow'])) * d.period
    assert np.max(np.abs(pumped - change('volume_pump'))) < 1e-3 * moved


def test_the_rod_volume_drives_the_accumulator_pressure():
    d = record(11, effect='relief_valve', brake_force=7000.0, duration=8.0)
    c, plant = d.clean, d.plant
    # Extending draws the rod's volume from the accumulator, retracting returns it.
    rod = plant['area_a'] - plant['area_b']
    stored = c['oil_accumulator'][0] - rod * (c['position'] - c['position'][0])
    volume = plant['accumulator_volume']
    predicted = ((plant['charge_pressure'] + tp.P_ATM)
                 * (volume / (volume - stored)) ** plant['polytropic_index'] - tp.P_ATM)
    # Only the oil's compression in the chambers and pump outlet is missing from the estimate.
    np.testing.assert_allclose(c['pressure_accumulator'], predicted, rtol=0.03)
    assert np.corrcoef(c['position'], c['pressure_accumulator'])[0, 1] < -0.9


def test_a_vapour_pocket_holds_the_cavitation_floor_and_keeps_the_oil_balance():
    plant = dict(record(0, duration=2.0).plant)
    # A heavy, unbraked mass coasting on when the valve reverses tears chamber A open.
    plant.update(moving_mass=3000.0, brake_force=0.0)
    rate = 1000.0
    commands = np.where(np.arange(600) < 300, 300.0, -300.0)
    c = open_loop(plant, commands, rate, substeps=128)
    floor = plant['cavitation_pressure']
    assert np.any(c['node_a'] < floor - 1e5)  # vapour appeared
    assert np.min(c['pressure_a']) == pytest.approx(floor)
    assert np.min(c['pressure_b']) >= floor
    total = c['oil_a'] + c['oil_b'] + c['oil_pump'] + c['oil_accumulator']
    assert np.ptp(total) < 1e-5 * plant['accumulator_volume']


def test_retracting_is_faster_than_extending_by_the_area_ratio():
    d = record(12, effect='none', brake_force=2000.0, duration=10.0)
    c, plant = d.clean, d.plant
    flow = c['pump_flow']
    # Steady motion: valve fully open, a fair flow, little acceleration.
    steady = (flow > 0.2 * plant['pump_displacement'] * 300.0) & (np.abs(c['acceleration']) < 0.05)
    extend = steady & (c['spool'] > 0.99)
    retract = steady & (c['spool'] < -0.99)
    assert extend.sum() > 100 and retract.sum() > 100
    per_flow_extend = np.median(c['velocity'][extend] / flow[extend])
    per_flow_retract = np.median(-c['velocity'][retract] / flow[retract])
    ratio = per_flow_retract / per_flow_extend
    assert ratio == pytest.approx(plant['area_a'] / plant['area_b'], rel=0.03)
    assert plant['area_a'] / plant['area_b'] == pytest.approx(1.46, abs=0.01)


def test_the_unloaded_motor_reaches_its_setpoint_within_its_time_constant():
    plant = dict(record(1, effect='none', duration=2.0).plant)
    plant['brake_force'] = 0.0  # the load cylinder unhooked
    rate = 4000.0
    step_at = 80
    commands = np.where(np.arange(800) >= step_at, 100.0, 0.0)
    c = open_loop(plant, commands, rate, substeps=32)
    speed = c['motor_speed']
    assert speed[-1] == pytest.approx(100.0, rel=0.01)
    rise = (np.argmax(speed >= 100.0 * (1.0 - math.exp(-1.0))) - step_at) / rate
    assert rise == pytest.approx(tp.datasheet()['motor_time_constant'], rel=0.4)


def test_the_motor_falls_short_of_its_setpoint_when_the_pump_pressure_exceeds_its_torque():
    plant = dict(record(1, effect='none', duration=2.0).plant)
    plant['brake_force'] = 7000.0
    rate = tp.RATE
    torque_max = plant['motor_torque_peak']
    pressure_max = torque_max * plant['pump_mechanical_efficiency'] / plant['pump_displacement']
    c = open_loop(plant, np.full(300, -150.0), rate)
    late = slice(100, 300)
    assert np.all(c['motor_speed'][late] < 0.5 * 150.0)
    np.testing.assert_allclose(c['motor_torque'][late], torque_max)
    dp = c['pressure_pump'] - c['pressure_accumulator']
    assert np.all(dp[late] > 0.95 * pressure_max)
    # The same rig extending against a light brake holds its set-point.
    plant['brake_force'] = 1000.0
    c = open_loop(plant, np.full(300, 150.0), rate)
    np.testing.assert_allclose(c['motor_speed'][late], 150.0, rtol=0.01)
    assert np.all(c['motor_torque'][late] < 0.7 * torque_max)


def test_in_closed_loop_the_torque_limit_is_reached_with_a_heavy_brake_and_not_a_light_one():
    heavy = record(12, effect='none', brake_force=6500.0, duration=10.0)
    light = record(12, effect='none', brake_force=2000.0, duration=10.0)
    for d, low, high in ((heavy, 0.05, 0.95), (light, 0.0, 0.02)):
        c = d.clean
        limited = c['motor_torque'] >= 0.999 * d.plant['motor_torque_peak']
        assert low <= limited.mean() <= high
    c = heavy.clean
    limited = c['motor_torque'] >= 0.999 * heavy.plant['motor_torque_peak']
    short = c['motor_speed_setpoint'] - c['motor_speed']
    assert np.median(short[limited]) > 20.0


def test_halving_the_integration_step_changes_the_outputs_by_much_less_than_the_noise(
        monkeypatch):
    coarse = record(12, effect='none', brake_force=6500.0, duration=10.0)
    monkeypatch.setattr(tp, 'SUBSTEPS', 2 * tp.SUBSTEPS)
    fine = tp.draw(12, effect='none', brake_force=6500.0, duration=10.0)
    for name, level in NOISY_CHANNELS.items():
        change = fine.clean[name] - coarse.clean[name]
        assert np.max(np.abs(change)) < 0.1 * coarse.noise[level], name
        assert np.sqrt(np.mean(change ** 2)) < 0.01 * coarse.noise[level], name


def test_halving_the_step_at_the_stiffest_corner_of_the_drawn_ranges_changes_nothing_seen():
    d = record(3, effect='coulomb_friction', size=tp.EFFECT_RANGES['coulomb_friction'][1],
               brake_force=tp.BRAKE_FORCE_RANGE[1], duration=6.0)
    low = {name: low for name, low, _ in tp._NUISANCE}
    high = {name: high for name, _, high in tp._NUISANCE}
    plant = dict(d.plant)
    # The brake's low-speed slope F_b / (v_b M) and the oil's stiffness at their largest.
    plant.update(moving_mass=low['moving_mass'], brake_velocity=low['brake_velocity'],
                 bulk_modulus=high['bulk_modulus'], dead_volume_a=low['dead_volume_a'],
                 dead_volume_b=low['dead_volume_b'])
    plant['load_mass'] = plant['moving_mass'] - low['piston_mass']
    reference, velocity = d.clean['reference'], d.clean['reference_velocity']
    coarse = tp.run(plant, reference, velocity)
    fine = tp.run(plant, reference, velocity, substeps=2 * tp.SUBSTEPS)
    for name, level in NOISY_CHANNELS.items():
        change = np.max(np.abs(fine[name] - coarse[name]))
        assert change < 0.1 * d.noise[level], name


def test_a_20_s_record_simulates_in_a_few_seconds():
    tp.draw(2, duration=1.0)  # compiled
    start = time.perf_counter()
    tp.draw(2, duration=20.0)
    assert time.perf_counter() - start < 5.0


@pytest.mark.parametrize('excitation', tp.EXCITATIONS)
@pytest.mark.parametrize('effect', tp.EFFECTS)
def test_every_effect_at_its_weakest_moves_the_measurements_beyond_three_noise_levels(
        effect, excitation):
    base = record(3, effect='none', excitation=excitation, duration=8.0)
    low, high = tp.effect_range(effect, base.parameters)
    weakest = high if effect == 'relief_valve' else low
    changed = tp.draw(3, effect=effect, size=weakest, excitation=excitation, duration=8.0)
    assert excess_over_noise(changed, base) > 3.0


@pytest.mark.parametrize('effect', tp.EFFECTS)
def test_an_effect_of_no_size_is_no_effect(effect):
    base = record(3, effect='none', duration=3.0)
    # A relief valve cracking at its setting is the healthy one.
    size = base.plant['relief_pressure'] if effect == 'relief_valve' else 0.0
    same = tp.draw(3, effect=effect, size=size, duration=3.0)
    assert excess_over_noise(same, base) == 0.0


def test_the_effect_sizes_are_drawn_within_the_record_ranges():
    for seed in range(40):
        d = tp.draw(seed, duration=0.05)
        if d.effect == 'none':
            assert d.size == 0.0
            continue
        low, high = tp.effect_range(d.effect, d.parameters)
        assert low <= d.size <= high
        pooled_low, pooled_high = tp.EFFECT_RANGES[d.effect]
        assert pooled_low <= low and high <= pooled_high


def test_the_leaking_relief_valve_and_the_deadzone_act_as_specified():
    relief = record(11, effect='relief_valve', brake_force=7000.0, duration=8.0)
    c, plant = relief.clean, relief.plant
    dp = c['pressure_pump'] - c['pressure_accumulator']
    expected = plant['relief_crack_gain'] * np.maximum(
        np.minimum(dp, plant['relief_pressure']) - plant['relief_crack_pressure'], 0.0)
    expected += plant['relief_gain'] * np.maximum(dp - plant['relief_pressure'], 0.0)
    np.testing.assert_allclose(c['relief_flow'], expected, rtol=1e-12, atol=1e-15)
    assert np.mean(c['relief_flow'] > 0.0) > 0.1
    dead = tp.draw(3, effect='pump_deadzone', size=30.0, duration=4.0)
    c = dead.clean
    assert np.all(c['pump_flow_geometric'][c['motor_speed'] <= 30.0] == 0.0)
    moving = c['motor_speed'] > 30.0
    np.testing.assert_allclose(c['pump_flow_geometric'][moving],
                               dead.plant['pump_displacement'] * (c['motor_speed'][moving] - 30))


@pytest.mark.parametrize(('seed', 'brake', 'excitation'),
                         [(20, 1000.0, 'sine_sum'), (21, 7000.0, 'steps')])
def test_the_brake_opposes_the_motion_and_the_accumulator_stays_in_its_range(
        seed, brake, excitation):
    d = record(seed, brake_force=brake, excitation=excitation, duration=10.0)
    c = d.clean
    assert np.all(c['brake_force'] * c['velocity'] >= 0.0)
    # The load cell pushes the rod in while it extends, out while it retracts.
    fast = np.abs(c['velocity']) > 5e-3
    assert np.all(np.sign(d.columns['load_force'][fast]) == np.sign(c['velocity'][fast]))
    assert np.all(c['pressure_accumulator'] > 0.3e6)
    assert np.all(c['pressure_accumulator'] < d.plant['relief_pressure'])
    assert np.all(c['oil_accumulator'] > 0.0)
    assert np.all((c['position'] > 0.0) & (c['position'] < d.plant['stroke']))


def test_the_measured_signals_follow_the_csv_conventions():
    d = record(12, effect='none', brake_force=2000.0, duration=10.0)
    m, c = d.columns, d.clean
    # The command's sign is the valve's side; the measured speed carries the same sign.
    running = c['motor_speed'] > 10.0 * d.noise['motor_speed']
    assert np.all(np.sign(m['motor_speed'][running]) == np.sign(m['motor_speed_command'][running]))
    assert np.all(np.abs(m['motor_speed_command']) <= tp.datasheet()['motor_speed_max'])
    # A positive command extends: the position, from the retracted end, rises.
    extending = (m['motor_speed_command'] > 50.0) & (c['spool'] > 0.99)
    assert np.all(c['velocity'][extending] > 0.0)
    assert np.all(m['pressure_a'] >= 0.0) and np.all(m['pressure_b'] <= 25e6)
    assert np.max(np.abs(m['position'] - c['position'])) < 6 * d.noise['position'] + 1e-6


@pytest.mark.parametrize('excitation', tp.EXCITATIONS)
def test_the_excitations_reverse_often_and_stay_near_mid_stroke(excitation):
    time_ = np.arange(4000) / tp.RATE
    maker = tp._sine_sum if excitation == 'sine_sum' else tp._steps
    for seed in range(5):
        x_ref, v_ref, _ = maker(np.random.default_rng(seed), time_)
        assert np.max(np.abs(x_ref - tp.MID_STROKE)) < 0.051
        assert np.max(np.abs(v_ref)) < 0.036
        # Through zero velocity (a reversal, or a stop and a start) at least 8 times in 20 s.
        assert np.sum(np.diff(np.sign(v_ref)) != 0) >= 8
        assert np.any(v_ref > 5e-3) and np.any(v_ref < -5e-3)
        # The velocity is the position's derivative.
        np.testing.assert_allclose(np.gradient(x_ref, time_)[1:-1], v_ref[1:-1], atol=2e-3)


def test_write_csv_writes_what_draw_holds(tmp_path):
    d = record(4, duration=2.0)
    path = tmp_path / 'all.csv'
    tp.write_csv(d, path)
    with path.open() as handle:
        header = next(csv.reader(handle))
    assert tuple(header) == tp.COLUMNS
    data = np.loadtxt(path, delimiter=',', skiprows=1)
    for i, name in enumerate(tp.COLUMNS):
        np.testing.assert_array_equal(data[:, i], d.columns[name])
    some = tmp_path / 'some.csv'
    tp.write_csv(d, some, columns=('position', 'pressure_b'))
    with some.open() as handle:
        assert next(csv.reader(handle)) == ['time', 'position', 'pressure_b']
    data = np.loadtxt(some, delimiter=',', skiprows=1)
    np.testing.assert_array_equal(data[:, 2], d.columns['pressure_b'])
    with pytest.raises(ValueError, match='unknown columns'):
        tp.write_csv(d, some, columns=('torque',))

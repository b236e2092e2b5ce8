"""Measured data for the diagnosis: CSV and bag reading, and the errors that name bad input."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_sim.diagnosis.data import (
    MIN_SAMPLES,
    Limits,
    check_columns,
    read_bag,
    read_csv,
    write_csv,
)
from exo_has_sim.diagnosis.fitting import output_weights
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.errors import DiagnosisError, MeasurementError
from exo_has_sim.parameters import load_parameters

HIP = Limits(stroke=0.13, motor_speed_max=418.9)
PERIOD = 0.005


def columns(samples=400, **extra):
    t = np.arange(samples) * PERIOD
    out = {'time': t, 'motor_speed_command': 100.0 * np.sin(2.0 * t),
           'position': 0.06 + 0.02 * np.sin(t), 'pressure_a': 3e6 + 1e5 * np.cos(t)}
    out.update(extra)
    return out


def write(path, table, header=None):
    names = header or list(table)
    lines = [','.join(names)]
    for row in zip(*(table[n] for n in names), strict=True):
        lines.append(','.join('' if isinstance(v, float) and math.isnan(v) else repr(float(v))
                              for v in row))
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return path


def test_a_csv_log_reads_back_as_written(tmp_path):
    table = columns(load_force=np.full(400, 300.0))
    m = read_csv(write(tmp_path / 'log.csv', table), limits=HIP)
    assert m.samples == 400 and m.plant == 'has'
    assert_allclose(m.period, PERIOD, rtol=1e-12)
    assert_allclose(m.input, table['motor_speed_command'], rtol=0, atol=0)
    assert_allclose(m.position, table['position'], rtol=0, atol=0)
    assert sorted(m.optional) == ['load_force', 'pressure_a']
    write_csv(m, tmp_path / 'again.csv')
    again = read_csv(tmp_path / 'again.csv', limits=HIP)
    assert_allclose(again.position, m.position, rtol=1e-8)


def test_missing_columns_are_listed_with_what_was_found(tmp_path):
    table = columns()
    del table['motor_speed_command']
    with pytest.raises(MeasurementError, match=r'missing column motor_speed_command \(required: '
                       r'time, motor_speed_command, position; found: time, position, '
                       r'pressure_a\)'):
        read_csv(write(tmp_path / 'log.csv', table))


def test_the_mass_plant_needs_a_force_column():
    with pytest.raises(MeasurementError, match='missing column force'):
        check_columns(columns(), 'mass', 'log')


def test_a_time_that_does_not_increase_is_named_by_its_row(tmp_path):
    table = columns()
    table['time'] = table['time'].copy()
    table['time'][100] = table['time'][99]
    # Row 1 is the header, so sample 100 is row 102.
    with pytest.raises(MeasurementError, match='time does not increase at row 102'):
        read_csv(write(tmp_path / 'log.csv', table))


def test_a_nan_run_is_located_by_rows_and_time(tmp_path):
    table = columns()
    table['position'] = table['position'].copy()
    table['position'][50:54] = np.nan
    table['position'][300] = np.nan
    with pytest.raises(MeasurementError, match=r'position is NaN in rows 52 to 55 '
                       r'\(t = 0.25 s\), 4 samples; 2 NaN runs in all'):
        read_csv(write(tmp_path / 'log.csv', table), limits=HIP)


def test_an_optional_column_nan_throughout_counts_as_not_measured():
    m = check_columns(columns(load_force=np.full(400, np.nan)), 'has', 'log', HIP)
    assert 'load_force' not in m.optional
    assert any('load_force is NaN throughout' in note for note in m.notes)


def test_a_position_in_millimetres_is_recognised():
    table = columns()
    table['position'] = table['position'] * 1e3
    with pytest.raises(MeasurementError, match=r'position looks like millimetres \(max 80 > '
                       r'stroke 0.13 m\)'):
        check_columns(table, 'has', 'log', HIP)


def test_a_motor_speed_in_rpm_is_recognised():
    table = columns()
    table['motor_speed_command'] = table['motor_speed_command'] * 60.0 / (2.0 * math.pi) * 20
    with pytest.raises(MeasurementError, match=r'motor_speed_command looks like r/min'):
        check_columns(table, 'has', 'log', HIP)


def test_a_pressure_in_megapascal_is_recognised():
    table = columns()
    table['pressure_a'] = table['pressure_a'] * 1e-6
    with pytest.raises(MeasurementError, match='pressure_a looks like MPa or bar'):
        check_columns(table, 'has', 'log', HIP)


def test_a_rod_side_pressure_in_bar_is_recognised_and_one_at_the_tank_in_pascal_is_not():
    table = columns()
    rng = np.random.default_rng(2)
    table['pressure_b'] = 1.5 + 0.3 * rng.standard_normal(len(table['time']))  # bar
    with pytest.raises(MeasurementError, match='pressure_b looks like MPa or bar'):
        check_columns(table, 'has', 'log', HIP)
    table['pressure_b'] = 0.15e6 + 20e3 * rng.standard_normal(len(table['time']))  # Pa
    assert check_columns(table, 'has', 'log', HIP).has('pressure_b')


def test_a_time_in_milliseconds_is_recognised():
    table = columns()
    table['time'] = table['time'] * 1e3
    with pytest.raises(MeasurementError, match='time looks like milliseconds'):
        check_columns(table, 'has', 'log', HIP)


def test_a_value_that_is_not_a_number_is_named_by_row_and_column(tmp_path):
    path = write(tmp_path / 'log.csv', columns())
    lines = path.read_text().splitlines()
    fields = lines[10].split(',')
    fields[2] = 'oops'
    lines[10] = ','.join(fields)
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(MeasurementError, match="row 11, column position: 'oops' is not a number"):
        read_csv(path)


def test_an_output_that_never_changes_is_named():
    flat = check_columns(columns(pressure_a=np.zeros(400)), 'has', 'flat.csv', HIP)
    with pytest.raises(DiagnosisError, match='pressure_a is 0 throughout the record'):
        output_weights(HasPlant(flat, load_parameters('hip')))


def test_too_short_a_record_is_refused():
    with pytest.raises(MeasurementError, match=f'at least {MIN_SAMPLES}'):
        check_columns(columns(samples=MIN_SAMPLES - 1), 'has', 'log')


def test_jittery_stamps_are_resampled_and_a_long_gap_is_refused():
    rng = np.random.default_rng(3)
    table = columns()
    table['time'] = table['time'] + rng.uniform(-0.2, 0.2, 400) * PERIOD
    m = check_columns(table, 'has', 'log', HIP)
    assert_allclose(np.diff(m.time), PERIOD, rtol=0.01)
    assert any('resampled' in note for note in m.notes)
    gap = columns()
    gap['time'] = np.where(np.arange(400) >= 200, gap['time'] + 0.1, gap['time'])
    with pytest.raises(MeasurementError, match=r'a gap of 0.105 s \(21.0 sample periods\)'):
        check_columns(gap, 'has', 'log', HIP)


def test_a_held_input_on_jittering_stamps_keeps_its_mean_over_each_grid_period():
    # A plant node's ticks: on the 5 ms grid, every fourth 0.4 ms late. The command sent at a
    # tick is held to the next; what the plant received over a grid period is its mean there,
    # not the value held at the grid instant (a whole period late after a late tick).
    table = columns()
    table['time'] = table['time'] + np.where(np.arange(400) % 4 == 1, 0.4e-3, 0.0)
    table['motor_speed_command'] = np.where(np.arange(400) % 4 < 2, 10.0, -10.0)
    m = check_columns(table, 'has', 'log', HIP)
    assert any('resampled' in note for note in m.notes)
    sent, grid = table['time'], m.time
    k = np.arange(1, 398)
    # Grid period k holds command k-1 until stamp k, then command k.
    share = (sent[k] - grid[k]) / m.period
    expected = share * table['motor_speed_command'][k - 1] \
        + (1.0 - share) * table['motor_speed_command'][k]
    assert_allclose(m.input[k], expected, atol=1e-9)
    # The volume a pump would have delivered is kept.
    assert_allclose(np.sum(m.input[:398]) * m.period,
                    np.sum(table['motor_speed_command'][:397] * np.diff(sent[:398]))
                    + table['motor_speed_command'][397] * (grid[398] - sent[397]), rtol=1e-9)


def test_one_joints_topics_are_read_from_a_bag(tmp_path):
    from rclpy.serialization import serialize_message

    from exo_has_common.bag import BagWriter
    from exo_has_msgs.msg import HasCommand, HasState

    samples = 300
    t0 = 1_700_000_000_000_000_000
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/left_knee/has_state', 'exo_has_msgs/msg/HasState')
        writer.add_topic('/left_knee/has_command', 'exo_has_msgs/msg/HasCommand')
        writer.add_topic('/right_hip/has_state', 'exo_has_msgs/msg/HasState')
        for k in range(samples):
            stamp = t0 + k * 5_000_000
            # The state's motor_speed_command, the command in force (the plant's initial
            # 3 rad/s before its first command), counts only before the first one recorded.
            state = HasState(joint='left_knee', position=0.05 + 1e-5 * k, pressure_a=2e6,
                             motor_speed=3.0, motor_speed_command=3.0, load_force=math.nan)
            state.header.stamp.sec, state.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            writer.write('/left_knee/has_state', stamp, serialize_message(state))
            other = HasState(joint='right_hip', position=0.1)
            other.header.stamp.sec, other.header.stamp.nanosec = state.header.stamp.sec, \
                state.header.stamp.nanosec
            writer.write('/right_hip/has_state', stamp, serialize_message(other))
            if k < 5:  # the recorder took the commands from the sixth state on
                continue
            # The controller answers 1 ms after the state, commanding k rad/s.
            command = HasCommand(joint='left_knee', motor_speed=1.0 * k, enable=k != 7)
            answer = stamp + 1_000_000
            command.header.stamp.sec, command.header.stamp.nanosec = divmod(answer,
                                                                          1_000_000_000)
            writer.write('/left_knee/has_command', answer, serialize_message(command))
    m = read_bag(tmp_path / 'bag', 'left_knee', HIP)
    assert m.samples == samples
    assert_allclose(m.period, 0.005, rtol=1e-9)
    expected = 1.0 * np.arange(samples)
    expected[7] = 0.0  # disabled: the motor stops
    expected[:5] = 3.0  # before the first command recorded: the one in force
    assert_allclose(m.input, expected)
    assert_allclose(m.position, 0.05 + 1e-5 * np.arange(samples), rtol=1e-12)
    assert sorted(m.optional) == ['motor_speed', 'pressure_a', 'pressure_b']  # load NaN
    with pytest.raises(MeasurementError, match='no messages on /left_hip/has_state'):
        read_bag(tmp_path / 'bag', 'left_hip', HIP)
    with pytest.raises(MeasurementError, match='unknown joint'):
        read_bag(tmp_path / 'bag', 'elbow', HIP)

import math

import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import HardwareConfigError
from exo_has_driver.hardware.units import DriveUnits, decode_sensors

STROKE = 0.13  # m


def test_full_pump_speed_is_copleys_velocity_units_through_counts_and_gear():
    units = DriveUnits()
    # 4000 r/min = 66.67 r/s * 4096 counts = 273 067 counts/s = 2 730 667 units of 0.1 counts/s.
    assert units.velocity_to_drive(4000.0 * 2.0 * math.pi / 60.0) == 2_730_667
    assert units.velocity_from_drive(2_730_667) == pytest.approx(418.879, abs=1e-3)
    geared = DriveUnits(encoder_counts=2000, gear_ratio=3.5, velocity_unit=1.0)
    assert geared.velocity_to_drive(2.0 * math.pi) == 7000
    assert geared.velocity_to_drive(-2.0 * math.pi) == -7000
    assert units.current_from_drive(-430) == pytest.approx(-4.30, abs=1e-12)


def test_speeds_beyond_the_integer32_range_clamp_and_nan_is_refused():
    units = DriveUnits()
    assert units.velocity_to_drive(math.inf) == 0x7FFFFFFF
    assert units.velocity_to_drive(-1e9) == -0x80000000
    with pytest.raises(HardwareConfigError, match='NaN speed'):
        units.velocity_to_drive(math.nan)


def test_ramps_convert_to_unsigned32_units_and_out_of_range_ramps_are_refused():
    units = DriveUnits()
    assert units.acceleration_to_drive(2.0 * math.pi) == 40960
    for bad in (0.0, -1.0, math.nan, 1e6):
        with pytest.raises(HardwareConfigError, match='must be positive and at most'):
            units.acceleration_to_drive(bad)


@pytest.mark.parametrize(('name', 'value'), [('encoder_counts', 0), ('encoder_counts', 1.5),
                                             ('gear_ratio', -1.0), ('velocity_unit', math.nan),
                                             ('current_unit', 0.0)])
def test_a_unit_that_is_not_positive_is_refused_by_name(name, value):
    with pytest.raises(HardwareConfigError, match=name):
        DriveUnits(**{name: value})


def test_a_sound_sample_converts_to_si_units():
    values = decode_sensors(65_432, 5_745, -12, -26_727, 0, STROKE)
    assert values.position == pytest.approx(0.065432, abs=1e-12)
    assert values.pressure_a == pytest.approx(5.745e6, abs=1e-6)
    assert values.pressure_b == pytest.approx(-12e3, abs=1e-9)
    assert values.velocity == pytest.approx(-0.026727, abs=1e-12)
    assert values.fault is None


def test_the_no_reading_sentinel_is_nan_and_a_fault():
    values = decode_sensors(10_000, cd.NO_READING_I16, 0, 0, cd.SENSOR_FAULT_PRESSURE_A, STROKE)
    assert math.isnan(values.pressure_a)
    assert values.fault is not None
    assert values.fault.channel == 'pressure_a'
    assert math.isnan(values.fault.value) and math.isnan(values.fault.limit)
    values = decode_sensors(cd.NO_READING_I32, 0, 0, 0, 0, STROKE)
    assert math.isnan(values.position)
    assert values.fault is not None and values.fault.channel == 'position'


def test_a_status_bit_alone_is_a_fault_of_its_channel():
    values = decode_sensors(10_000, 100, 0, 5, cd.SENSOR_FAULT_VELOCITY, STROKE)
    assert values.velocity == pytest.approx(5e-6, abs=1e-15)
    assert values.fault is not None
    assert (values.fault.channel, values.fault.value) == ('velocity', pytest.approx(5e-6))
    assert 'status 0x0008' in values.fault.text


@pytest.mark.parametrize(('raw', 'channel', 'value', 'limit'), [
    ((131_001, 0, 0), 'position', 0.131001, 0.131),
    ((-1_001, 0, 0), 'position', -0.001001, -0.001),
    ((50_000, 30_001, 0), 'pressure_a', 30.001e6, 30e6),
    ((50_000, 0, -101), 'pressure_b', -0.101e6, -0.1e6),
])
def test_values_outside_the_sensor_ranges_are_faults_with_the_bound_crossed(raw, channel, value,
                                                                           limit):
    values = decode_sensors(*raw, 0, 0, STROKE)
    assert values.fault is not None
    assert values.fault.channel == channel
    assert values.fault.value == pytest.approx(value, abs=1e-9)
    assert values.fault.limit == pytest.approx(limit, abs=1e-9)


def test_values_at_the_range_bounds_are_sound():
    assert decode_sensors(131_000, 30_000, -100, 0, 0, STROKE).fault is None
    assert decode_sensors(-1_000, 0, 0, 0, 0, STROKE).fault is None

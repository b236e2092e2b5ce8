"""The simulated sensor board: sampling, sentinels, saturation; silence of the bus."""

from __future__ import annotations

import math
import time

import pytest
from devices_bench import Bench, BenchMaster, FakeClock

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.sensor_board import encode_reading
from exo_has_driver.errors import FaultInjectionError

TPDO1, TPDO2 = 0x191, 0x291


def sample(master: BenchMaster, clock: FakeClock) -> tuple[tuple[int, ...], tuple[int, ...]]:
    tpdo1, tpdo2 = master.sync(clock, expect=(TPDO1, TPDO2))
    return cd.SENSOR_TPDO1.unpack(tpdo1), cd.SENSOR_TPDO2.unpack(tpdo2)


def test_encode_reading_rounds_saturates_short_of_the_sentinel_and_marks_nan() -> None:
    assert encode_reading(0.0123456, 1e-6, -32767, 32767, -32768) == 12346
    assert encode_reading(4e7, 1e3, -32767, 32767, -32768) == 32767
    assert encode_reading(-4e7, 1e3, -32767, 32767, -32768) == -32767
    assert encode_reading(math.nan, 1e3, -32767, 32767, -32768) == -32768


def test_the_board_reports_the_plant_in_its_units_and_counts_syncs(bench: Bench) -> None:
    rig, master, clock = bench
    master.nmt(0x01)
    (position, pressure_a, pressure_b), (velocity, status, counter) = sample(master, clock)
    plant = rig.joints['left_hip'].plant.sample()
    assert position == pytest.approx(plant.position * 1e6, abs=0.5)
    assert pressure_a == pytest.approx(plant.pressure_a * 1e-3, abs=0.5)
    assert pressure_b == 0
    assert velocity == pytest.approx(plant.velocity * 1e6, abs=0.5)
    assert status == 0
    counters = [counter] + [sample(master, clock)[1][2] for _ in range(3)]
    assert counters == [1, 2, 3, 4]


def test_a_nan_reading_sends_the_sentinel_and_sets_its_status_bit(bench: Bench) -> None:
    rig, master, clock = bench
    master.nmt(0x01)
    rig.set_sensor('left_hip', 'pressure_a', math.nan)
    rig.set_sensor('left_hip', 'velocity', math.nan)
    (position, pressure_a, _), (velocity, status, _) = sample(master, clock)
    assert pressure_a == cd.NO_READING_I16
    assert velocity == cd.NO_READING_I32
    assert status == cd.SENSOR_FAULT_PRESSURE_A | cd.SENSOR_FAULT_VELOCITY
    assert 0 < position < 130_000
    rig.set_sensor('left_hip', 'pressure_a', None)
    rig.set_sensor('left_hip', 'velocity', None)
    (_, pressure_a, _), (_, status, _) = sample(master, clock)
    assert pressure_a > 1000  # kPa: the load's pressure again
    assert status == 0


def test_out_of_range_readings_saturate_instead_of_wrapping(bench: Bench) -> None:
    rig, master, clock = bench
    master.nmt(0x01)
    rig.set_sensor('left_hip', 'position', 0.5)  # m: far beyond the 130 mm stroke
    rig.set_sensor('left_hip', 'pressure_a', 4e7)  # Pa: over the I16 range of kPa
    rig.set_sensor('left_hip', 'pressure_b', -4e7)
    rig.set_sensor('left_hip', 'velocity', 1e4)  # m/s: over the I32 range of um/s
    (position, pressure_a, pressure_b), (velocity, status, _) = sample(master, clock)
    assert (position, pressure_a, pressure_b) == (500_000, 32767, -32767)
    assert velocity == 2**31 - 1
    assert status == 0
    with pytest.raises(FaultInjectionError, match='unknown sensor channel'):
        rig.set_sensor('left_hip', 'temperature', 1.0)


def test_silence_stops_every_frame_until_cleared(bench: Bench) -> None:
    rig, master, clock = bench
    master.nmt(0x01)
    sample(master, clock)
    rig.set_silent('all')
    time.sleep(0.05)  # frames already on their way
    master.clear()
    for _ in range(3):
        clock.now += 0.06  # heartbeats due
        master.send(cd.SYNC_COB_ID)
        master.node(17).sdo.RESPONSE_TIMEOUT = 0.2
        with pytest.raises(Exception, match='No SDO response'):
            master.node(17).sdo[0x1000].raw  # noqa: B018
    time.sleep(0.1)
    assert master.frames == []
    rig.clear('all')
    clock.now += 0.06
    master.wait_for(cd.HEARTBEAT_BASE + 17)
    assert sample(master, clock)[1][2] > 0

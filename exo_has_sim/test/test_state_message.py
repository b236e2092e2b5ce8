"""A joint's sample as a HasState message, and message stamps in nanoseconds."""

import math
from dataclasses import dataclass

import pytest
from rclpy.time import Time

from exo_has_msgs.msg import HasState
from exo_has_sim.plant import PlantSample
from exo_has_sim.state_message import NS_PER_S, has_state, nanoseconds, set_stamp, stamp_ns
from exo_has_sim.valve import ValveMode


def test_a_plant_sample_is_a_has_state_with_its_load_and_no_motor_current():
    sample = PlantSample(position=0.021, velocity=0.003, pressure_a=4.5e6, pressure_b=0.0,
                         motor_speed=150.0, motor_speed_command=160.0, load_force=850.0,
                         valve_mode=ValveMode.RELIEF)
    state = has_state('left_hip', 12 * NS_PER_S + 5, sample, load_force=sample.load_force)
    assert isinstance(state, HasState)
    assert (state.joint, state.position, state.velocity, state.pressure_a, state.pressure_b,
            state.motor_speed, state.motor_speed_command, state.load_force, state.valve_mode) \
        == ('left_hip', 0.021, 0.003, 4.5e6, 0.0, 150.0, 160.0, 850.0, HasState.VALVE_RELIEF)
    assert math.isnan(state.motor_current)  # the plant does not model it
    assert (state.header.stamp.sec, state.header.stamp.nanosec) == (12, 5)


@dataclass(frozen=True)
class Measured:
    """A sample as the hardware gives it: no load force, a NaN where a channel has none."""

    position: float = math.nan
    velocity: float = math.nan
    pressure_a: float = 1.0e6
    pressure_b: float = math.nan
    motor_speed: float = 0.0
    motor_speed_command: float = 0.0
    valve_mode: int = ValveMode.FREE


def test_the_values_not_measured_stay_nan():
    state = has_state('right_knee', 0, Measured(), motor_current=2.5)
    assert math.isnan(state.position) and math.isnan(state.velocity)
    assert math.isnan(state.pressure_b) and math.isnan(state.load_force)
    assert state.motor_current == 2.5 and state.pressure_a == 1.0e6
    assert (state.header.stamp.sec, state.header.stamp.nanosec) == (0, 0)


@pytest.mark.parametrize('ns', [0, 1, NS_PER_S - 1, NS_PER_S, 1_700_000_000_999_999_999])
def test_a_stamp_splits_into_seconds_and_nanoseconds_as_rclpy_does(ns):
    state = HasState()
    set_stamp(state.header, ns)
    expected = Time(nanoseconds=ns).to_msg()
    assert (state.header.stamp.sec, state.header.stamp.nanosec) == (expected.sec,
                                                                   expected.nanosec)
    assert 0 <= state.header.stamp.nanosec < NS_PER_S
    assert stamp_ns(state.header) == ns


@pytest.mark.parametrize(('seconds', 'ns'), [
    (0.0, 0), (1.5, 1_500_000_000), (1_700_000_000.25, 1_700_000_000_250_000_000),
    (math.nextafter(2.0, 0.0), 1_999_999_999)])
def test_seconds_become_whole_nanoseconds_rounded_down(seconds, ns):
    assert nanoseconds(seconds) == ns

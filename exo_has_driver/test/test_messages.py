"""The driver's message conversions: safety events, and the hardware's samples as HasState."""

import math
from unittest.mock import Mock, call

import pytest

from exo_has_driver.events import Event, SafetyKind, Severity
from exo_has_driver.hardware.config import JointSample
from exo_has_driver.messages import log_event, safety_event
from exo_has_msgs.msg import HasState, SafetyEvent
from exo_has_sim.state_message import has_state, nanoseconds, stamp_ns
from exo_has_sim.valve import ValveMode


def test_a_safety_event_carries_every_field_of_the_event_and_its_stamp():
    event = Event('left_knee', SafetyKind.OVER_PRESSURE, Severity.WARN, 16.5e6, 16.2e6, False,
                  'left_knee: over-pressure')
    message = safety_event(event, 1_700_000_000_123_456_789)
    assert isinstance(message, SafetyEvent)
    assert (message.joint, message.kind, message.severity, message.value, message.limit,
            message.latched, message.text) == (
        'left_knee', SafetyEvent.KIND_OVER_PRESSURE, SafetyEvent.SEVERITY_WARN, 16.5e6, 16.2e6,
        False, 'left_knee: over-pressure')
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (1_700_000_000,
                                                                       123_456_789)
    assert stamp_ns(message.header) == 1_700_000_000_123_456_789


def test_a_safety_event_without_a_value_carries_nan_and_a_whole_second_stamp():
    event = Event('', SafetyKind.RESET, Severity.INFO, math.nan, math.nan, False, 'reset')
    message = safety_event(event, 42_000_000_000)
    assert math.isnan(message.value) and math.isnan(message.limit)
    assert (message.joint, message.kind, message.latched) == ('', SafetyEvent.KIND_RESET, False)
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (42, 0)


@pytest.mark.parametrize(('severity', 'level'), [
    (Severity.FATAL, 'error'), (Severity.ERROR, 'error'), (Severity.WARN, 'warning'),
    (Severity.INFO, 'info')])
def test_an_event_is_logged_at_its_severity(severity, level):
    logger = Mock(spec=['error', 'warning', 'info'])
    log_event(logger, Event('', SafetyKind.E_STOP, severity, math.nan, math.nan, True, 'text'))
    assert logger.method_calls == [getattr(call, level)('text')]


def test_a_hardware_sample_is_a_has_state_stamped_at_its_receive_time_without_a_load_force():
    sample = JointSample('right_knee', 1_700_000_000.25, 0.02, -0.01, 5.0e6, math.nan, 120.0,
                         125.0, 1.5, ValveMode.ASSIST, 'operation enabled', False, 7)
    state = has_state(sample.joint, nanoseconds(sample.stamp), sample,
                      motor_current=sample.motor_current)
    assert isinstance(state, HasState)
    assert (state.joint, state.position, state.velocity, state.pressure_a, state.motor_speed,
            state.motor_speed_command, state.motor_current, state.valve_mode) == (
        'right_knee', 0.02, -0.01, 5.0e6, 120.0, 125.0, 1.5, HasState.VALVE_ASSIST)
    assert math.isnan(state.pressure_b)  # a channel without reading
    assert math.isnan(state.load_force)  # not measured on the hardware
    assert (state.header.stamp.sec, state.header.stamp.nanosec) == (1_700_000_000, 250_000_000)

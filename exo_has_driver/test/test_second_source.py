"""The one second-source rule, free of ROS: the driver's and the watchdog core's judgement."""

import pytest

from exo_has_common.joints import JOINT_NAMES
from exo_has_driver.events import SafetyKind, Severity
from exo_has_driver.safety import Watchdog
from exo_has_driver.safety_limits import SafetyLimits
from exo_has_driver.second_source import second_source
from exo_has_sim.parameters import load_parameters

STATE = '/left_hip/has_state'
COMMAND = '/left_hip/has_command'


def test_one_publisher_or_none_is_no_second_source():
    assert second_source('left_hip', STATE, []) is None
    assert second_source('left_hip', STATE, ['/left_hip_plant']) is None
    assert second_source('left_hip', COMMAND, ['/pd_controller']) is None


def test_two_publishers_are_a_second_source_named_in_order():
    condition = second_source('left_hip', COMMAND, ['/rogue', '/pd_controller'])
    assert condition is not None
    assert (condition.key, condition.joint, condition.kind, condition.value, condition.limit) \
        == (('second source', COMMAND), 'left_hip', SafetyKind.SECOND_SOURCE, 2.0, 1.0)
    assert condition.text == ('left_hip: second source: 2 publishers on /left_hip/has_command '
                              '(/pd_controller, /rogue), where one is allowed')


def test_the_stop_sources_do_not_count_beside_the_commander():
    # The driver's commands: the controller, and the watchdog's stop commands.
    assert second_source('left_hip', COMMAND, ['/pd_controller', '/watchdog'],
                         stop_sources=('/watchdog',)) is None
    condition = second_source('left_hip', COMMAND, ['/pd_controller', '/watchdog', '/rogue'],
                              stop_sources=('/watchdog',))
    assert condition is not None and condition.value == 2.0
    assert '/watchdog' not in condition.text


def test_the_driver_is_the_one_source_of_its_states_any_other_is_a_second():
    assert second_source('left_hip', STATE, [], own='this driver') is None
    condition = second_source('left_hip', STATE, ['/left_hip_plant'], own='this driver')
    assert condition is not None and condition.value == 2.0
    assert condition.text == ('left_hip: second source: 2 publishers on /left_hip/has_state '
                              '(/left_hip_plant, this driver), where one is allowed')


@pytest.mark.parametrize('publishers', [
    [], ['/left_hip_plant'], ['/left_hip_plant', '/rogue_plant'],
    ['/a', '/b', 'an unnamed node (publisher gid 0a0b)'],
])
def test_the_watchdog_core_judges_a_topic_by_the_same_rule(publishers):
    params = {'hip': load_parameters('hip'), 'knee': load_parameters('knee')}
    watchdog = Watchdog({joint: SafetyLimits.from_parameters(
        params['hip' if joint.endswith('hip') else 'knee']) for joint in JOINT_NAMES}, 0.0)
    events = watchdog.on_sources('left_hip', STATE, publishers)
    condition = second_source('left_hip', STATE, publishers)
    if condition is None:
        assert events == []
        assert not watchdog.stopped
        return
    (event,) = events
    assert (event.joint, event.kind, event.severity, event.value, event.limit, event.text) == (
        condition.joint, condition.kind, Severity.FATAL, condition.value, condition.limit,
        condition.text)
    # And the same condition refuses a reset while it holds.
    (refused,) = watchdog.reset(0.0)
    assert refused.kind == SafetyKind.SECOND_SOURCE
    assert condition.text in refused.text

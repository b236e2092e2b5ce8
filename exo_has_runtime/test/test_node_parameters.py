import math

import pytest
from rcl_interfaces.msg import ParameterType
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from exo_has_common.realtime import MAX_PRIORITY
from exo_has_runtime.node_parameters import declare, declare_realtime_priority


def make_node(context, **overrides):
    return Node('parameters_under_test', context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])


def test_a_float_parameter_carries_its_description_range_and_read_only_flag(ros_context):
    node = make_node(ros_context)
    assert declare(node, 'rate', 200.0, 'publication rate [Hz]', (1.0, 2000.0)) == 200.0
    described = node.describe_parameter('rate')
    assert described.description == 'publication rate [Hz]'
    assert described.read_only
    assert described.type == ParameterType.PARAMETER_DOUBLE
    (limits,) = described.floating_point_range
    assert (limits.from_value, limits.to_value) == (1.0, 2000.0)
    assert not described.integer_range
    node.destroy_node()


def test_an_integer_default_gives_an_integer_range_and_a_given_value_is_taken(ros_context):
    node = make_node(ros_context, count=7)
    assert declare(node, 'count', 0, 'how many', (0, 100)) == 7
    (limits,) = node.describe_parameter('count').integer_range
    assert (limits.from_value, limits.to_value, limits.step) == (0, 100, 1)
    node.destroy_node()


def test_a_value_outside_the_bounds_is_refused_naming_the_parameter(ros_context):
    node = make_node(ros_context, rate=0.5)
    with pytest.raises(InvalidParameterValueException, match='rate'):
        declare(node, 'rate', 200.0, 'publication rate [Hz]', (1.0, 2000.0))
    node.destroy_node()


def test_a_parameter_shared_by_joints_of_one_type_is_declared_once(ros_context):
    node = make_node(ros_context, **{'hip.kp': 2.5})
    first = declare(node, 'hip.kp', 1.0, 'position gain', (0.0, 10.0))
    again = declare(node, 'hip.kp', 1.0, 'position gain', (0.0, 10.0))
    assert first == again == 2.5
    node.destroy_node()


def test_a_parameter_that_may_change_at_run_time_is_not_read_only(ros_context):
    node = make_node(ros_context)
    declare(node, 'gain', 1.0, 'a gain', (0.0, 2.0), read_only=False)
    assert not node.describe_parameter('gain').read_only
    assert node.set_parameters([Parameter('gain', value=math.pi / 2)])[0].successful
    assert not node.set_parameters([Parameter('gain', value=3.0)])[0].successful
    node.destroy_node()


def test_the_realtime_priority_is_bounded_by_what_the_scheduler_allows(ros_context):
    node = make_node(ros_context)
    assert declare_realtime_priority(node, 'the loop') == 0
    described = node.describe_parameter('realtime_priority')
    assert 'the loop' in described.description
    assert described.integer_range[0].to_value == MAX_PRIORITY
    node.destroy_node()

import itertools
import math
import os
import signal
import time

import pytest

from exo_has_runtime.errors import (
    ExternalShutdownException,
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterNotDeclaredException,
    TopicTypeMismatchError,
)
from exo_has_runtime.standalone import (
    Node,
    Parameter,
    QoSProfile,
    SetParametersResult,
    SingleThreadedExecutor,
    get_message,
)
from exo_has_runtime.standalone.parameters import parameter_descriptor

HasCommand = get_message('exo_has_msgs/msg/HasCommand')
HasState = get_message('exo_has_msgs/msg/HasState')
FloatingPointRange = get_message('rcl_interfaces/msg/FloatingPointRange')


def spin_until(executor, predicate, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def test_a_message_published_in_one_node_reaches_another(ros_context):
    talker = Node('talker', context=ros_context)
    listener = Node('listener', context=ros_context)
    received = []
    listener.create_subscription(HasCommand, 'left_hip/has_command', received.append, 10)
    publisher = talker.create_publisher(HasCommand, 'left_hip/has_command', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(listener)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    publisher.publish(HasCommand(joint='left_hip', motor_speed=-12.5, enable=True))
    assert spin_until(executor, lambda: received)
    assert received[0].motor_speed == -12.5 and received[0].joint == 'left_hip'


def test_publishing_a_message_of_another_type_is_a_type_error(ros_context):
    node = Node('talker', context=ros_context)
    publisher = node.create_publisher(HasCommand, 'cmd', 10)
    with pytest.raises(TypeError, match=r'takes exo_has_msgs/msg/HasCommand, not .*HasState'):
        publisher.publish(HasState())


def test_one_topic_with_two_types_in_one_process_is_refused(ros_context):
    node = Node('talker', context=ros_context)
    node.create_publisher(HasCommand, 'shared', 10)
    with pytest.raises(TopicTypeMismatchError, match=r"'rt/shared'.*HasCommand.*HasState"):
        node.create_subscription(HasState, 'shared', lambda _: None, 10)


def test_timers_fire_at_their_period_and_count_missed_periods(ros_context):
    node = Node('ticker', context=ros_context)
    stamps = []
    timer = node.create_timer(0.01, lambda: stamps.append(time.monotonic()))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    assert spin_until(executor, lambda: len(stamps) >= 20)
    periods = [b - a for a, b in itertools.pairwise(stamps)]
    assert sorted(periods)[len(periods) // 2] == pytest.approx(0.01, abs=0.003)
    time.sleep(0.055)  # five periods pass without spinning
    before = len(stamps)
    executor.spin_once(timeout_sec=0.001)
    assert len(stamps) == before + 1 and timer.missed_periods >= 4


def test_parameters_come_from_the_command_line_and_the_params_file(tmp_path, ros_context):
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    rate: 1000.0\n    joint: left_knee\n')
    ros_context.arguments.parameter_overrides.clear()
    node = Node('plant', context=ros_context, cli_args=[
        '--ros-args', '--params-file', str(params), '-p', 'gain:=35.0',
        '-p', 'bulk_modulus:=1.2e9'])
    assert node.declare_parameter('rate', 200.0).value == 1000.0
    assert node.declare_parameter('joint', 'left_hip').value == 'left_knee'
    assert node.declare_parameter('gain', 1.0).value == 35.0
    assert node.declare_parameter('bulk_modulus', 1.0e9).value == 1.2e9
    assert node.declare_parameter('untouched', 7).value == 7
    assert node.get_parameter('use_sim_time').value is False


def test_a_value_of_the_wrong_type_names_the_parameter(ros_context):
    node = Node('plant', context=ros_context, cli_args=['--ros-args', '-p', 'rate:=fast'])
    with pytest.raises(InvalidParameterTypeException,
                       match=r"'rate' of node /plant: value 'fast' \(from -p\) is of type STRING"):
        node.declare_parameter('rate', 200.0)
    node.declare_parameter('gain', 35.0)
    result = node.set_parameters([Parameter('gain', value=35)])[0]
    assert not result.successful and "'gain'" in result.reason and 'INTEGER' in result.reason


def test_ranges_and_callbacks_guard_parameter_values(ros_context):
    node = Node('plant', context=ros_context, cli_args=['--ros-args', '-p', 'rate:=5000.0'])
    descriptor = parameter_descriptor(
        floating_point_range=[FloatingPointRange(from_value=1.0, to_value=2000.0)])
    with pytest.raises(InvalidParameterValueException, match=r"'rate'.*outside \[1.0, 2000.0\]"):
        node.declare_parameter('rate', 200.0, descriptor)
    node.declare_parameter('gain', 35.0)
    node.add_on_set_parameters_callback(lambda ps: SetParametersResult(
        successful=all(p.value >= 0 for p in ps), reason='gains are non-negative'))
    assert node.set_parameters([Parameter('gain', value=40.0)])[0].successful
    rejected = node.set_parameters([Parameter('gain', value=-1.0)])[0]
    assert not rejected.successful and 'non-negative' in rejected.reason
    assert node.get_parameter('gain').value == 40.0
    with pytest.raises(ParameterNotDeclaredException, match="'nope' of node /plant"):
        node.get_parameter('nope')
    with pytest.raises(InvalidParameterValueException):
        node.declare_parameter('other', math.nan, descriptor)


def test_remaps_and_namespace_take_effect(ros_context):
    node = Node('controller', context=ros_context, cli_args=[
        '--ros-args', '-r', '__ns:=/exo', '-r', '__node:=hip_controller',
        '-r', 'reference:=/gait/joint_reference'])
    assert node.get_fully_qualified_name() == '/exo/hip_controller'
    assert node.get_logger().name == 'exo.hip_controller'
    subscription = node.create_subscription(
        get_message('sensor_msgs/msg/JointState'), 'reference', lambda _: None, 10)
    publisher = node.create_publisher(HasCommand, 'left_hip/has_command', 10)
    assert subscription.topic_name == '/gait/joint_reference'
    assert publisher.topic_name == '/exo/left_hip/has_command'


def test_use_sim_time_makes_the_clock_and_timers_follow_the_clock_topic(ros_context):
    node = Node('plant', context=ros_context, cli_args=['--ros-args', '-p', 'use_sim_time:=true'])
    assert node.get_clock().now().nanoseconds == 0  # no /clock yet
    clock_source = Node('clock_source', context=ros_context)
    clock_type = get_message('rosgraph_msgs/msg/Clock')
    clock_publisher = clock_source.create_publisher(clock_type, '/clock', QoSProfile(depth=1))
    ticks = []
    node.create_timer(0.5, lambda: ticks.append(node.get_clock().now().nanoseconds))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    assert spin_until(executor, lambda: clock_publisher.get_subscription_count() == 1)
    for step in range(1, 9):  # 8 simulated quarter seconds, much faster than real time
        clock_publisher.publish(clock_type(clock=get_message('builtin_interfaces/msg/Time')(
            sec=100 + step // 4, nanosec=(step % 4) * 250_000_000)))
        assert spin_until(executor, lambda s=step: node.get_clock().now().nanoseconds
                          == (100 * 10**9 + s * 250_000_000), timeout_s=2.0)
        executor.spin_once(timeout_sec=0.01)
    assert node.get_clock().ros_time_is_active
    # Simulated time is 0 until the first /clock, whose jump to 100.25 s fires the timer once;
    # then it keeps its 0.5 s grid, as rcl timers do.
    assert ticks == [100_250_000_000, 100_500_000_000, 101_000_000_000, 101_500_000_000,
                     102_000_000_000]


def test_shutdown_from_a_callback_ends_spin_normally(ros_context):
    node = Node('quitter', context=ros_context)
    node.create_timer(0.01, ros_context.shutdown)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.spin()  # returns, as rclpy's spin does once the context is shut down
    assert not ros_context.ok()
    node.destroy_node()  # still safe after the context is gone


def test_sigterm_ends_spin_with_external_shutdown(ros_context):
    node = Node('terminated', context=ros_context)
    node.create_timer(0.01, lambda: os.kill(os.getpid(), signal.SIGTERM))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    with pytest.raises(ExternalShutdownException):
        executor.spin()
    assert not ros_context.ok()
    node.destroy_node()
    ros_context.try_shutdown()


def test_a_callback_may_destroy_another_subscription_or_its_node(ros_context):
    node = Node('self_destroying', context=ros_context)
    publisher = node.create_publisher(HasCommand, 'a', 10)
    other = node.create_subscription(HasCommand, 'b', lambda _: None, 10)
    node.create_publisher(HasCommand, 'b', 10).publish(HasCommand())
    calls = []

    def on_a(message):
        calls.append(message)
        node.destroy_subscription(other)
        node.destroy_node()

    node.create_subscription(HasCommand, 'a', on_a, 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    publisher.publish(HasCommand())
    assert spin_until(executor, lambda: calls)
    executor.spin_once(timeout_sec=0.05)


def test_a_malformed_string_from_a_peer_is_dropped_with_an_error_not_a_crash(ros_context):
    node = Node('listener', context=ros_context)
    string_type = get_message('std_msgs/msg/String')
    received = []
    node.create_subscription(string_type, 'text', received.append, 10)
    publisher = node.create_publisher(string_type, 'text', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    publisher.publish(b'\x00\x01\x00\x00\x03\x00\x00\x00\xff\xfe\x00\x00')  # not UTF-8
    publisher.publish(string_type(data='ok'))
    assert spin_until(executor, lambda: received and received[-1].data == 'ok')
    assert received[0].data == '\ufffd\ufffd'  # replaced, as rclpy decodes


def test_a_shut_down_context_forgets_its_nodes_and_a_failed_node_leaves_the_graph(ros_context):
    Node('forgotten', context=ros_context)
    ros_context.shutdown()
    ros_context.init(['test'])
    with pytest.raises(InvalidParameterTypeException, match='use_sim_time'):
        Node('broken', context=ros_context, cli_args=['--ros-args', '-p', 'use_sim_time:=1'])
    Node('kept', context=ros_context)
    assert [entry.name for entry in ros_context._nodes.values()] == ['kept']


def test_a_parameter_declared_by_type_has_no_value_until_given_one(ros_context):
    node = Node('typed', context=ros_context)
    parameter = node.declare_parameter('gain', Parameter.Type.DOUBLE)
    assert parameter.type_ == Parameter.Type.NOT_SET and parameter.value is None
    assert not node.set_parameters([Parameter('gain', value='high')])[0].successful
    assert node.set_parameters([Parameter('gain', value=2.0)])[0].successful
    with pytest.raises(ParameterNotDeclaredException):
        node.set_parameters([Parameter('undeclared', value=1.0)])


def test_a_two_argument_callback_gets_the_message_info_with_the_publication_time(ros_context):
    talker = Node('info_talker', context=ros_context)
    listener = Node('info_listener', context=ros_context)
    received = []
    listener.create_subscription(HasCommand, 'info/has_command',
                                 lambda message, info: received.append((message, info)), 10)
    publisher = talker.create_publisher(HasCommand, 'info/has_command', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(listener)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    before = time.time_ns()
    publisher.publish(HasCommand(joint='left_hip', motor_speed=3.0, enable=True))
    assert spin_until(executor, lambda: received)
    message, info = received[0]
    assert message.motor_speed == 3.0
    assert before <= info['source_timestamp'] <= info['received_timestamp'] <= time.time_ns()


def test_a_callback_of_three_arguments_is_refused(ros_context):
    node = Node('three_arguments', context=ros_context)
    with pytest.raises(TypeError, match='one argument'):
        node.create_subscription(HasCommand, 'three/has_command', lambda a, b, c: None, 10)


def test_a_paced_executor_does_not_wake_for_messages_and_hands_them_over_at_its_tick(
        ros_context):
    talker = Node('paced_talker', context=ros_context)
    listener = Node('paced_listener', context=ros_context)
    received, ticks = [], []
    listener.create_subscription(HasCommand, 'paced/has_command', received.append,
                                 QoSProfile(depth=50))
    # A tick within the executor's longest wait (100 ms, after which it also takes messages).
    timer = listener.create_timer(0.08, lambda: ticks.append(len(received)))
    publisher = talker.create_publisher(HasCommand, 'paced/has_command', 50)
    executor = SingleThreadedExecutor(context=ros_context, wake_on_messages=False)
    executor.add_node(listener)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    for _ in range(5):  # let discovery settle: graph events wake a paced executor too
        executor.spin_once(timeout_sec=0.1)
    timer.reset()
    ticks.clear()
    received.clear()
    for k in range(20):
        publisher.publish(HasCommand(joint='left_hip', motor_speed=float(k), enable=True))
    started = time.monotonic()
    executor.spin_once(timeout_sec=2.0)
    # It slept through the arrivals until the tick, then took all of them, in order, first.
    assert time.monotonic() - started > 0.05
    assert ticks == [20]
    assert [m.motor_speed for m in received] == [float(k) for k in range(20)]

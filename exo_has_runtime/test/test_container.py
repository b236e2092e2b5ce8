"""Several nodes in one process: the container's command line, its errors, and a real run."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time

import pytest

from exo_has_runtime.container import ComponentSpec, node_class, split_arguments
from exo_has_runtime.errors import ContainerArgumentError
from exo_has_runtime.processes import NodeProcess


def test_arguments_before_the_first_node_are_global_and_each_node_keeps_its_own():
    global_arguments, specs = split_arguments([
        '--ros-args', '-p', 'use_sim_time:=true', '--',
        '--node', 'a.b:C', '--ros-args', '-r', '__node:=one', '-p', 'joint:=left_hip',
        '--node', 'a.b:D'])
    assert global_arguments == ['--ros-args', '-p', 'use_sim_time:=true', '--']
    assert specs == [
        ComponentSpec('a.b:C', ('--ros-args', '-r', '__node:=one', '-p', 'joint:=left_hip')),
        ComponentSpec('a.b:D', ())]


def test_a_spec_gives_back_the_command_line_it_was_read_from():
    spec = ComponentSpec('a.b:C', ('--ros-args', '-p', 'x:=1'))
    assert split_arguments(spec.command_line())[1] == [spec]


@pytest.mark.parametrize(('argv', 'wording'), [
    ([], 'no node to run'),
    (['--ros-args', '-p', 'x:=1'], 'no node to run'),
    (['--node'], 'names no node class'),
    (['--node', '--ros-args'], 'must be followed by package.module:Class'),
])
def test_a_command_line_without_a_node_class_is_refused_by_name(argv, wording):
    with pytest.raises(ContainerArgumentError, match=wording):
        split_arguments(argv)


@pytest.mark.parametrize(('target', 'wording'), [
    ('exo_has_sim.plant_node', 'expected package.module:Class'),
    ('exo_has_sim.no_such_module:PlantNode', 'cannot import'),
    ('exo_has_sim.plant_node:NoSuchNode', 'has no rclpy Node class NoSuchNode'),
    ('exo_has_sim.plant_node:Plant', 'has no rclpy Node class Plant'),
])
def test_an_unknown_node_class_is_named_in_the_error(target, wording):
    with pytest.raises(ContainerArgumentError, match=wording):
        node_class(target)


@pytest.mark.process
def test_an_unknown_node_class_ends_the_container_with_one_line_and_exit_code_2():
    result = subprocess.run(
        [sys.executable, '-m', 'exo_has_runtime.container', '--node', 'exo_has_sim:Nope'],
        capture_output=True, text=True, timeout=60, cwd=tempfile.gettempdir())
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "[FATAL] [container]: node class 'exo_has_sim:Nope': exo_has_sim has no rclpy Node "
        'class Nope']


@pytest.mark.process
def test_two_composed_plants_each_take_their_own_parameters_and_stop_cleanly(ros_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from exo_has_msgs.msg import HasState

    node = Node('container_listener', context=ros_context)
    states: dict[str, list[HasState]] = {'left_hip': [], 'right_knee': []}
    for joint, received in states.items():
        node.create_subscription(HasState, f'{joint}/has_state', received.append,
                                 qos_profile_sensor_data)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    arguments: list[str] = []
    for joint in states:
        arguments += ['--node', 'exo_has_sim.plant_node:PlantNode', '--ros-args',
                      '-r', f'__node:={joint}_plant', '-p', f'joint:={joint}']
    container = NodeProcess('exo_has_runtime.container', arguments)
    try:
        deadline = time.monotonic() + 60.0  # the first start compiles the model
        while (not all(states.values()) and time.monotonic() < deadline
               and container.process.poll() is None):
            executor.spin_once(timeout_sec=0.1)
    finally:
        code = container.stop(timeout_s=10.0)
        executor.shutdown()
        node.destroy_node()
    output = container.output
    assert all(states.values()), f'not every plant published; the output:\n{output}'
    assert {s.joint for s in states['left_hip']} == {'left_hip'}
    assert {s.joint for s in states['right_knee']} == {'right_knee'}
    assert code == 0, output
    # Each node under its own name, with its own parameters, and its last words logged.
    assert '[left_hip_plant]: left_hip plant ready (hip parameters' in output
    assert '[right_knee_plant]: right_knee plant ready (knee parameters' in output
    assert '[right_knee_plant]: right_knee plant: ' in output

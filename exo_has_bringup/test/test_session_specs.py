"""What a session runs: its processes, and the nodes composed into one."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from exo_has_bringup.plan import COMPOSITION, SessionConfig, compose, node_specs
from exo_has_common.joints import JOINT_NAMES
from exo_has_runtime.container import split_arguments

PLANTS = tuple(f'{joint}_plant' for joint in JOINT_NAMES)


def test_by_default_the_four_plants_share_one_container_and_the_rest_run_alone():
    specs = node_specs(SessionConfig(), Path('bag'))
    assert [spec.name for spec in specs] == [
        'recorder', 'plants', 'pd_controller', 'watchdog', 'gait_publisher']
    plants = specs[1]
    assert plants.module == 'exo_has_runtime.container'
    assert plants.members == PLANTS == COMPOSITION['plants']
    _, components = split_arguments(plants.arguments)
    assert [c.target for c in components] == ['exo_has_sim.plant_node:PlantNode'] * 4
    # Each plant keeps its own node name and joint.
    for joint, component in zip(JOINT_NAMES, components, strict=True):
        assert f'__node:={joint}_plant' in component.arguments
        assert f'joint:={joint}' in component.arguments


def test_an_empty_composition_runs_every_node_in_its_own_process():
    specs = node_specs(SessionConfig(composition={}), Path('bag'))
    assert [spec.name for spec in specs] == [
        'recorder', *PLANTS, 'pd_controller', 'watchdog', 'gait_publisher']
    assert all(spec.module != 'exo_has_runtime.container' for spec in specs)


def test_the_can_hardware_composes_nothing_by_default():
    specs = node_specs(SessionConfig(hardware='can'), Path('bag'))
    assert 'plants' not in [spec.name for spec in specs]


def test_the_robot_hardware_runs_the_loop_and_its_bridge_in_place_of_the_three_nodes():
    config = SessionConfig(hardware='robot', rate=250.0, stale_periods=30, can_bitrate=2_000_000,
                           node_arguments={'pd_controller': ('-p', 'knee.kp:=30000.0')})
    specs = {spec.name: spec for spec in node_specs(config, Path('bag'))}
    assert list(specs) == ['recorder', 'can_devices', 'robot_loop', 'robot_bridge',
                           'gait_publisher']
    loop = ' '.join(specs['robot_loop'].arguments)
    bridge = ' '.join(specs['robot_bridge'].arguments)
    channel = re.search(r'--channel (\S+)', ' '.join(specs['can_devices'].arguments)).group(1)
    assert f'--channel {channel}' in loop and '--rate 250.0' in loop
    assert '--stale-periods 30' in loop and '--bitrate 2000000' in loop
    directory = re.search(r'--socket-dir (\S+)', loop).group(1)
    assert f'socket_dir:={directory}' in bridge and 'rate:=250.0' in bridge
    assert 'knee.kp:=30000.0' in bridge  # the controller's gains go to the bridge
    assert len(directory.encode()) < 90  # a socket's path in it fits sun_path's 108 bytes
    # The bridge alone reads the reference beside the recorder; no command topic is recorded.
    assert 'wait_for_subscribers:=2' in ' '.join(specs['gait_publisher'].arguments)
    assert 'has_command' not in ' '.join(specs['recorder'].arguments)
    other = node_specs(SessionConfig(hardware='robot'), None)
    assert re.search(r'--socket-dir (\S+)', ' '.join(other[1].arguments)).group(1) != directory


def test_a_container_is_ready_only_once_every_member_said_so_in_any_order():
    specs = node_specs(SessionConfig(), None)
    ready = next(spec for spec in specs if spec.name == 'plants').ready
    lines = [f'[INFO] [{joint}_plant]: {joint} plant ready (...)' for joint in JOINT_NAMES]
    assert re.search(ready, '\n'.join(reversed(lines)))
    assert not re.search(ready, '\n'.join(lines[:3]))


def test_a_container_starts_with_its_earliest_member():
    specs = node_specs(SessionConfig(), None)
    composed = compose(specs, 'control', ('pd_controller', 'gait_publisher'))
    control = next(spec for spec in composed if spec.name == 'control')
    assert control.stage == 1  # the controller's stage; the gait publisher's is 4


@pytest.mark.parametrize(('members', 'wording'), [
    (('pd_controller', 'no_such_node'), 'no_such_node: no such node'),
    (('can_devices',), 'no such node'),
])
def test_composing_an_unknown_node_is_refused_by_name(members, wording):
    with pytest.raises(ValueError, match=wording):
        compose(node_specs(SessionConfig(), None), 'x', members)


def test_the_simulated_can_devices_cannot_be_composed():
    specs = node_specs(SessionConfig(hardware='can'), None)
    with pytest.raises(ValueError, match='can_devices: it is not a node class'):
        compose(specs, 'x', ('can_devices', 'driver'))


def test_extra_arguments_reach_the_node_they_name_and_no_other():
    config = SessionConfig(composition={}, node_arguments={
        'watchdog': ('-p', 'batch:=false'), 'pd_controller': ('-p', 'hip.kp:=30.0')})
    arguments = {spec.name: spec.arguments for spec in node_specs(config, Path('bag'))}
    assert arguments['watchdog'][-2:] == ('-p', 'batch:=false')
    # The controller judges a gain change at the session's rate, which it is given first.
    assert arguments['pd_controller'] == ('--ros-args', '-p', f'rate:={config.rate}', '-p',
                                          'hip.kp:=30.0')
    assert not any('batch:=false' in a for name, a in arguments.items() if name != 'watchdog')


@pytest.mark.parametrize('hardware', ['plants', 'can', 'robot'])
def test_the_sessions_realtime_priority_reaches_the_joints_and_not_the_controller(hardware):
    config = SessionConfig(hardware=hardware, realtime_priority=20, composition={})
    arguments = {spec.name: ' '.join(spec.arguments) for spec in node_specs(config, None)}
    assert 'realtime_priority' not in arguments.get('pd_controller', '')
    assert 'realtime_priority' not in arguments.get('robot_bridge', '')
    joints = {'can': ['driver'], 'robot': ['robot_loop'],
              'plants': [f'{joint}_plant' for joint in JOINT_NAMES]}[hardware]
    if hardware != 'plants':  # the simulated hardware one level under the robot's threads
        assert '--realtime-priority 19' in arguments['can_devices']
    for name in joints:
        assert 'realtime_priority:=20' in arguments[name] \
            or '--realtime-priority 20' in arguments[name], name


def test_extra_arguments_for_an_unknown_node_are_refused_by_name():
    with pytest.raises(ValueError, match='unknown node left_hip_plant: expected among'):
        SessionConfig(node_arguments={'left_hip_plant': ('-p', 'rate:=100.0')})

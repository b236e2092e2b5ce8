"""Bad input across processes: a clear message naming the problem, and nobody crashes."""

import time
from pathlib import Path

import pytest

from exo_has_runtime.processes import NodeProcess

pytestmark = pytest.mark.process  # every test here starts processes

PEERS = 'exo_has_runtime.topic_tool'


def test_a_subscriber_of_another_type_on_one_topic_receives_nothing_and_both_keep_running():
    with NodeProcess(PEERS, ['record', '/mixed=exo_has_msgs/msg/HasState', '--duration', '30',
                             '--name', 'state_listener']) as listener:
        listener.wait_for_output('READY')
        with NodeProcess(PEERS, ['publish', '/mixed=exo_has_msgs/msg/HasCommand={}',
                                 '--no-wait', '--period', '0.05', '--duration', '30',
                                 '--name', 'command_talker']) as talker:
            talker.wait_for_output('PUBLISHED', timeout_s=10)
            time.sleep(1.0)
            assert talker.process.poll() is None and listener.process.poll() is None
            assert '{"topic"' not in listener.output  # nothing of the wrong type delivered


def test_an_unknown_type_name_fails_that_process_with_a_clear_error():
    with NodeProcess(PEERS, ['record', '/x=exo_has_msgs/msg/HasComand']) as peer:
        assert peer.wait(timeout_s=10) == 2
        assert ("message type 'exo_has_msgs/msg/HasComand' is unknown here: exo_has_msgs.msg "
                'has no message HasComand') in peer.output
        assert 'Traceback' not in peer.output


@pytest.mark.parametrize(('module', 'arguments', 'message'), [
    pytest.param('exo_has_runtime.examples.command_talker', ['-p', 'rate:=200'],
                 "cannot start: Trying to set parameter 'rate' to '200' of type 'INTEGER', "
                 "expecting type 'DOUBLE'", id='a wrongly typed parameter'),
    pytest.param('exo_has_sim.plant_node', ['-p', 'joint:=left_hip', '-p', 'rate:=5000.0'],
                 'Parameter rate out of range Min: 1.0, Max: 2000.0, value: 5000.0',
                 id='a parameter out of its range'),
    pytest.param('exo_has_sim.plant_node', ['-p', 'joint:=left_ankle'],
                 "cannot start: unknown joint 'left_ankle': expected one of left_hip, "
                 'left_knee, right_hip, right_knee', id='an unknown joint'),
])
def test_a_bad_configuration_fails_the_node_with_one_line_naming_the_problem(
        module, arguments, message):
    # 60 s: a plant's first start compiles the model.
    with NodeProcess(module, ['--ros-args', *arguments]) as node:
        assert node.wait(timeout_s=60) == 1
        assert message in node.output
        assert 'Traceback' not in node.output


def test_a_malformed_params_file_fails_the_node_naming_the_file(tmp_path: Path):
    params = tmp_path / 'broken.yaml'
    params.write_text('pd_controller:\n  ros__parameters: [kp\n', encoding='utf-8')
    with NodeProcess('exo_has_control.pd_controller',
                     ['--ros-args', '--params-file', str(params)]) as controller:
        assert controller.wait(timeout_s=30) == 2
        assert 'cannot start: bad ROS arguments' in controller.output
        assert str(params) in controller.output
        assert 'Traceback' not in controller.output


def test_a_nan_command_is_refused_by_the_plant_which_keeps_publishing():
    with NodeProcess('exo_has_sim.plant_node', ['--ros-args', '-p', 'joint:=left_knee']) as plant:
        plant.wait_for_output('plant ready', timeout_s=120)
        command = ('/left_knee/has_command=exo_has_msgs/msg/HasCommand='
                   '{"joint": "left_knee", "motor_speed": NaN, "enable": true}')
        # Publishing outlasts discovery (up to about 3 s on a loaded machine here): a clean
        # CI run saw every NaN of a 3 s burst sent before the plant had matched.
        with NodeProcess(PEERS, ['publish', command, '--qos', 'best_effort,volatile,10',
                                 '--no-wait', '--period', '0.05', '--duration', '15']) as talker:
            talker.wait_for_output('PUBLISHED', timeout_s=10)
            plant.wait_for_output(r'ERROR.*non-finite|ERROR.*NaN|ERROR.*nan', timeout_s=10)
        with NodeProcess(PEERS, ['record', '/left_knee/has_state=exo_has_msgs/msg/HasState',
                                 '--qos', 'best_effort,volatile,10', '--count', '5']) as states:
            assert states.wait(timeout_s=15) == 0
        assert plant.process.poll() is None
        assert 'Traceback' not in plant.output

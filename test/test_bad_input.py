"""Bad input across processes: a clear message, and nobody crashes."""

import time

from exo_has_runtime.testing.processes import NodeProcess

PEERS = 'exo_has_runtime.testing.peers'


def test_publisher_and_subscriber_of_different_types_on_one_topic_warn_and_keep_running():
    with NodeProcess(PEERS, ['record', '/mixed=exo_has_msgs/msg/HasState', '--duration', '30',
                             '--name', 'state_listener']) as listener:
        listener.wait_for_output('READY')
        with NodeProcess(PEERS, ['publish', '/mixed=exo_has_msgs/msg/HasCommand={}',
                                 '--no-wait', '--period', '0.05', '--duration', '30',
                                 '--name', 'command_talker']) as talker:
            warning = ("topic 'rt/mixed': a publisher in another process uses type "
                       'exo_has_msgs::msg::dds_::HasCommand_, this process uses '
                       'exo_has_msgs::msg::dds_::HasState_; they will not communicate')
            listener.wait_for_output(warning, timeout_s=10)
            talker.wait_for_output('subscriber in another process uses type '
                                   'exo_has_msgs::msg::dds_::HasState_', timeout_s=10)
            time.sleep(0.3)
            assert talker.process.poll() is None and listener.process.poll() is None
            assert '{"topic"' not in listener.output  # nothing of the wrong type delivered


def test_an_unknown_type_name_fails_that_process_with_a_clear_error():
    with NodeProcess(PEERS, ['record', '/x=exo_has_msgs/msg/HasComand']) as peer:
        assert peer.wait(timeout_s=10) != 0
        assert ("unknown message type 'exo_has_msgs/msg/HasComand': package 'exo_has_msgs' has "
                'no message of that name') in peer.output


def test_a_wrongly_typed_parameter_fails_the_node_naming_the_parameter():
    with NodeProcess('exo_has_runtime.demo.command_talker',
                     ['--ros-args', '-p', 'rate:=200']) as talker:
        assert talker.wait(timeout_s=10) != 0
        assert ("parameter 'rate' of node /command_talker: value 200 (from -p) is of type "
                'INTEGER, expected DOUBLE') in talker.output

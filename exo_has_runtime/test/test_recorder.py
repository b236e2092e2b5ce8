import json
import re
import signal
import statistics
import time

import pytest
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime

from exo_has_runtime.bag import BagWriter, bag_topics, read_messages, recover_bag
from exo_has_runtime.standalone import Node, SingleThreadedExecutor
from exo_has_runtime.standalone.messages import default_registry
from exo_has_runtime.standalone.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from exo_has_runtime.testing.peers import fill_message
from exo_has_runtime.testing.processes import NodeProcess

RECORDER = 'exo_has_runtime.recorder'
REPLAY = 'exo_has_runtime.replay'
PEERS = 'exo_has_runtime.testing.peers'
COMMAND = 'exo_has_msgs/msg/HasCommand'
EVENT = 'exo_has_msgs/msg/SafetyEvent'
JOINTS = 'sensor_msgs/msg/JointState'
REGISTRY = default_registry()
RELIABLE = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE,
               _QosTime(0, 0), _QosTime(0, 0), QosLiveliness.AUTOMATIC, _QosTime(0, 0), False)


def recorder_args(bag, *parameters):
    args = ['--ros-args', '-p', f'output:={bag}', '-p', 'discovery_period:=0.1']
    for parameter in parameters:
        args += ['-p', parameter]
    return args


def cdr(type_name, fields):
    return REGISTRY.serialize(fill_message(REGISTRY.get_message(type_name)(), fields))


@pytest.mark.parametrize('stop_signal', [signal.SIGINT, signal.SIGTERM],
                         ids=['SIGINT', 'SIGTERM'])
def test_the_recorder_closes_its_bag_with_every_message_on_sigint_and_sigterm(tmp_path,
                                                                             stop_signal):
    bag = tmp_path / 'bag'
    command, joints = {'joint': 'left_hip', 'motor_speed': 1.5}, {'name': ['x'], 'position': [1.0]}
    with NodeProcess(RECORDER, recorder_args(bag)) as recorder:
        recorder.wait_for_output('opened bag', timeout_s=60)
        # The publisher publishes once the recorder subscribed to both topics (every message of
        # a reliable topic then arrives), until its duration is over.
        with NodeProcess(PEERS, ['publish', f'/a={COMMAND}={json.dumps(command)}',
                                 f'/b={JOINTS}={json.dumps(joints)}', '--period', '0.02',
                                 '--duration', '1.5']) as publisher:
            assert publisher.wait(timeout_s=60) == 0
        recorder.wait_for_output(rf'recording 2 topics to {re.escape(str(bag))}')
        time.sleep(0.3)  # the last messages' way through DDS
        recorder.process.send_signal(stop_signal)
        assert recorder.wait(timeout_s=10) == 0
    published = publisher.output.count('PUBLISHED')
    assert published >= 5, publisher.output
    assert f'closed {bag}: {2 * published} messages (/a: {published}, /b: {published})' \
        in recorder.output
    assert (bag / 'metadata.yaml').is_file()
    with read_messages(bag) as messages:
        received = [(m.topic, m.data) for m in messages]
    assert sorted(set(received)) == [('/a', cdr(COMMAND, command)), ('/b', cdr(JOINTS, joints))]
    topics = bag_topics(bag)
    assert [(t.topic, t.msgtype, t.count) for t in topics] == [
        ('/a', COMMAND, published), ('/b', JOINTS, published)]
    assert topics[0].offered_qos[0].reliability == QosReliability.RELIABLE


def test_a_latched_event_published_before_the_recorder_started_is_recorded(tmp_path):
    bag = tmp_path / 'bag'
    event = {'kind': 12, 'severity': 3, 'latched': True, 'text': 'e-stop'}
    with NodeProcess(PEERS, ['publish', f'/safety_events={EVENT}={json.dumps(event)}', '--qos',
                             'reliable,transient_local,10', '--no-wait', '--duration', '30']
                     ) as publisher:
        publisher.wait_for_output('PUBLISHED', timeout_s=60)
        # A relative name, resolved as the node resolves it.
        with NodeProcess(RECORDER, recorder_args(bag, "topics:=['safety_events']")) as recorder:
            recorder.wait_for_output('recording 1 topics', timeout_s=60)
            time.sleep(0.5)
    assert f'closed {bag}: 1 messages (/safety_events: 1)' in recorder.output
    with read_messages(bag) as messages:
        assert [m.data for m in messages] == [cdr(EVENT, event)]
    offered = bag_topics(bag)[0].offered_qos[0]
    assert (offered.reliability, offered.durability) == (QosReliability.RELIABLE,
                                                         QosDurability.TRANSIENT_LOCAL)


def test_a_recorder_killed_with_sigkill_loses_no_more_than_its_last_flush_period(tmp_path):
    bag = tmp_path / 'bag'
    with NodeProcess(RECORDER, recorder_args(bag, 'flush_period:=0.2')) as recorder, \
            NodeProcess(PEERS, ['publish', f'/a={COMMAND}={{"motor_speed": 2.5}}', '--period',
                                '0.01', '--duration', '60']) as publisher:
        recorder.wait_for_output('recording 1 topics', timeout_s=60)
        publisher.wait_for_output('PUBLISHED', timeout_s=60)
        time.sleep(0.5)
        published_before = publisher.output.count('PUBLISHED')
        time.sleep(0.6)  # three flush periods, and then some
        recorder.kill()
        published = publisher.output.count('PUBLISHED')
    assert not (bag / 'metadata.yaml').exists()

    report = recover_bag(bag)

    assert published_before <= report.messages['/a'] <= published
    with read_messages(bag) as messages:
        assert {m.data for m in messages} == {cdr(COMMAND, {'motor_speed': 2.5})}


def test_a_replayed_bag_gives_the_same_bytes_in_order_at_twice_the_speed(tmp_path):
    source, replayed = tmp_path / 'source', tmp_path / 'replayed'
    start_ns, expected = 1_700_000_000_000_000_000, []
    with BagWriter(source) as writer:
        writer.add_topic('/left_hip/has_command', COMMAND, [RELIABLE])
        writer.add_topic('/joint_reference', JOINTS, [RELIABLE])
        for i in range(40):
            # Irregular gaps of 30 to 60 ms, so order and timing both show.
            stamp = start_ns + sum(30_000_000 + (k % 4) * 10_000_000 for k in range(i))
            topic, data = ('/left_hip/has_command', cdr(COMMAND, {'motor_speed': float(i)})) \
                if i % 3 else ('/joint_reference', cdr(JOINTS, {'position': [float(i)]}))
            writer.write(topic, stamp, data)
            expected.append((topic, stamp, data))
    topics = "topics:=['/left_hip/has_command', '/joint_reference']"
    with NodeProcess(RECORDER, recorder_args(replayed, topics)):
        with NodeProcess(REPLAY, [str(source), '--rate', '2', '--wait-for-subscribers']
                         ) as replay:
            assert replay.wait(timeout_s=60) == 0
        assert 'replayed 40 messages' in replay.output
        time.sleep(0.3)
    with read_messages(replayed) as messages:
        received = list(messages)
    assert [(m.topic, m.data) for m in received] == [(t, d) for t, _, d in expected]
    # Arrival against the bag's time at rate 2, less the median (the transport's latency).
    lags_s = [(m.timestamp_ns - received[0].timestamp_ns - (stamp - start_ns) / 2) * 1e-9
              for m, (_, stamp, _) in zip(received, expected, strict=True)]
    errors_s = [lag - statistics.median(lags_s) for lag in lags_s]
    assert max(abs(error) for error in errors_s) < 0.025, errors_s
    assert sorted(abs(error) for error in errors_s)[len(errors_s) * 9 // 10] < 0.010, errors_s


def test_the_graph_gives_each_publishers_offered_qos_as_rclpy_does(ros_context):
    node = Node('probe', context=ros_context)
    node.create_publisher(REGISTRY.get_message(COMMAND), 'latched', QoSProfile(
        depth=7, reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.create_publisher(REGISTRY.get_message(COMMAND), 'everything',
                          QoSProfile(history=HistoryPolicy.KEEP_ALL))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    deadline = time.monotonic() + 10
    while len(node.get_publishers_info_by_topic('latched')) < 1 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    (latched,) = node.get_publishers_info_by_topic('latched')
    assert latched.topic_type == COMMAND and latched.endpoint_type == 'PUBLISHER'
    offered = latched.qos_profile
    assert (offered.history, offered.depth, offered.reliability, offered.durability) == (
        HistoryPolicy.KEEP_LAST, 7, ReliabilityPolicy.BEST_EFFORT,
        DurabilityPolicy.TRANSIENT_LOCAL)
    (everything,) = node.get_publishers_info_by_topic('/everything')
    assert everything.qos_profile.history == HistoryPolicy.KEEP_ALL
    assert node.get_subscriptions_info_by_topic('latched') == []

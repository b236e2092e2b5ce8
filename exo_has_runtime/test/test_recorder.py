import re
import signal
import statistics
import subprocess
import sys
import threading
import time

import pytest
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import QosDurability, QosReliability
from sensor_msgs.msg import JointState

from exo_has_common.bag import BagWriter, bag_topics, offered_qos, read_messages, recover_bag
from exo_has_msgs.msg import HasCommand, SafetyEvent
from exo_has_runtime.processes import NodeProcess, tethered
from exo_has_runtime.recording import subscription_qos

RECORDER = 'exo_has_runtime.recorder'
REPLAY = 'exo_has_runtime.replay'
COMMAND = 'exo_has_msgs/msg/HasCommand'
EVENT = 'exo_has_msgs/msg/SafetyEvent'
JOINTS = 'sensor_msgs/msg/JointState'
RELIABLE = QoSProfile(depth=10)


def recorder_args(bag, *parameters):
    args = ['--ros-args', '-p', f'output:={bag}', '-p', 'discovery_period:=0.1']
    for parameter in parameters:
        args += ['-p', parameter]
    return args


def wait_for_subscribers(publishers, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while any(p.get_subscription_count() == 0 for p in publishers):
        assert time.monotonic() < deadline, 'the recorder never subscribed'
        time.sleep(0.02)


def read_back(bag):
    with read_messages(bag) as messages:
        return list(messages)


# Batches a second apart: the last messages reach the bag only through the batch taken when
# the recorder stops. A callback per message: poll_period 0.
@pytest.mark.process
@pytest.mark.parametrize('poll_period', [1.0, 0.0], ids=['batches', 'callbacks'])
@pytest.mark.parametrize('stop_signal', [signal.SIGINT, signal.SIGTERM],
                         ids=['SIGINT', 'SIGTERM'])
def test_the_recorder_closes_its_bag_with_every_message_on_sigint_and_sigterm(
        tmp_path, ros_context, stop_signal, poll_period):
    bag = tmp_path / 'bag'
    node = Node('test_publisher', context=ros_context)
    command_out = node.create_publisher(HasCommand, '/a', RELIABLE)
    joints_out = node.create_publisher(JointState, '/b', RELIABLE)
    arguments = recorder_args(bag, "topics:=['/a', 'b']", f'poll_period:={poll_period}')
    with NodeProcess(RECORDER, arguments) as recorder:
        recorder.wait_for_output('opened bag', timeout_s=60)
        wait_for_subscribers([command_out, joints_out])
        recorder.wait_for_output(rf'recording 2 topics to {re.escape(str(bag))}')
        started_ns = time.time_ns()
        for i in range(25):
            command_out.publish(HasCommand(joint='left_hip', motor_speed=float(i)))
            joints_out.publish(JointState(name=['x'], position=[float(i)]))
            time.sleep(0.02)
        time.sleep(0.3)  # the last messages' way through DDS
        stopped_ns = time.time_ns()
        recorder.process.send_signal(stop_signal)
        assert recorder.wait(timeout_s=10) == 0
    node.destroy_node()
    assert f'closed {bag}: 50 messages (/a: 25, /b: 25)' in recorder.output
    assert (bag / 'metadata.yaml').is_file()
    received = read_back(bag)
    commands = [deserialize_message(m.data, HasCommand) for m in received if m.topic == '/a']
    joints = [deserialize_message(m.data, JointState) for m in received if m.topic == '/b']
    assert [c.motor_speed for c in commands] == [float(i) for i in range(25)]
    assert [list(j.position) for j in joints] == [[float(i)] for i in range(25)]
    # Stamped at reception, on the system clock: inside the publishing, in order.
    stamps = [m.timestamp_ns for m in received]
    assert started_ns <= stamps[0] and stamps[-1] <= stopped_ns and stamps == sorted(stamps)
    topics = bag_topics(bag)
    assert [(t.topic, t.msgtype, t.count) for t in topics] == [
        ('/a', COMMAND, 25), ('/b', JOINTS, 25)]
    assert topics[0].offered_qos[0].reliability == QosReliability.RELIABLE


@pytest.mark.process
def test_a_latched_event_published_before_the_recorder_started_is_recorded(tmp_path,
                                                                          ros_context):
    bag = tmp_path / 'bag'
    node = Node('test_publisher', context=ros_context)
    events = node.create_publisher(SafetyEvent, '/safety_events', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    event = SafetyEvent(kind=12, severity=3, latched=True, text='e-stop')
    events.publish(event)
    # A relative name, resolved as the node resolves it.
    with NodeProcess(RECORDER, recorder_args(bag, "topics:=['safety_events']")) as recorder:
        recorder.wait_for_output('recording 1 topics', timeout_s=60)
        time.sleep(0.5)
    node.destroy_node()
    assert f'closed {bag}: 1 messages (/safety_events: 1)' in recorder.output
    (recorded,) = read_back(bag)
    assert deserialize_message(recorded.data, SafetyEvent).text == 'e-stop'
    offered = bag_topics(bag)[0].offered_qos[0]
    assert (offered.reliability, offered.durability) == (QosReliability.RELIABLE,
                                                         QosDurability.TRANSIENT_LOCAL)


@pytest.mark.process
def test_a_recorder_killed_with_sigkill_loses_no_more_than_its_last_flush_period(tmp_path,
                                                                                ros_context):
    bag = tmp_path / 'bag'
    node = Node('test_publisher', context=ros_context)
    commands = node.create_publisher(HasCommand, '/a', RELIABLE)
    published = []
    stop = threading.Event()

    def publish_at_100_hz():
        while not stop.is_set():
            commands.publish(HasCommand(motor_speed=float(len(published))))
            published.append(time.monotonic())
            time.sleep(0.01)

    # Every topic of the graph (rosout and parameter_events too, as ros2 bag record -a).
    with NodeProcess(RECORDER, recorder_args(bag, 'flush_period:=0.2')) as recorder:
        recorder.wait_for_output('opened bag', timeout_s=60)
        wait_for_subscribers([commands])
        publisher = threading.Thread(target=publish_at_100_hz)
        publisher.start()
        try:
            time.sleep(0.5)
            published_before = len(published)
            time.sleep(0.6)  # three flush periods, and then some
            recorder.kill()
        finally:
            stop.set()
            publisher.join()
    node.destroy_node()
    assert not (bag / 'metadata.yaml').exists()

    report = recover_bag(bag)

    assert published_before <= report.messages['/a'] <= len(published)
    speeds = [deserialize_message(m.data, HasCommand).motor_speed for m in read_back(bag)
              if m.topic == '/a']
    assert speeds == [float(i) for i in range(len(speeds))]


@pytest.mark.process
def test_a_replayed_bag_gives_the_recorded_bytes_in_order_at_twice_the_speed(tmp_path):
    source, replayed = tmp_path / 'source', tmp_path / 'replayed'
    start_ns, expected = 1_700_000_000_000_000_000, []
    reliable = offered_qos(RELIABLE)
    with BagWriter(source) as writer:
        writer.add_topic('/left_hip/has_command', COMMAND, [reliable])
        writer.add_topic('/joint_reference', JOINTS, [reliable])
        for i in range(40):
            # Irregular gaps of 30 to 60 ms, so order and timing both show.
            stamp = start_ns + sum(30_000_000 + (k % 4) * 10_000_000 for k in range(i))
            topic, data = ('/left_hip/has_command',
                           serialize_message(HasCommand(motor_speed=float(i)))) if i % 3 \
                else ('/joint_reference', serialize_message(JointState(position=[float(i)])))
            writer.write(topic, stamp, data)
            expected.append((topic, stamp, data))
    topics = "topics:=['/left_hip/has_command', '/joint_reference']"
    with NodeProcess(RECORDER, recorder_args(replayed, topics)):
        with NodeProcess(REPLAY, [str(source), '--rate', '2', '--wait-for-subscribers']
                         ) as replay:
            assert replay.wait(timeout_s=60) == 0
        assert 'replayed 40 messages' in replay.output
        time.sleep(0.3)
    received = read_back(replayed)
    # The bytes as recorded, unchanged but for DDS's padding of a payload to 4 bytes.
    assert [(m.topic, m.data) for m in received] == [
        (t, d + bytes(-len(d) % 4)) for t, _, d in expected]
    # Arrival against the bag's time at rate 2, less the median (the transport's latency).
    lags_s = [(m.timestamp_ns - received[0].timestamp_ns - (stamp - start_ns) / 2) * 1e-9
              for m, (_, stamp, _) in zip(received, expected, strict=True)]
    errors_s = [lag - statistics.median(lags_s) for lag in lags_s]
    assert max(abs(error) for error in errors_s) < 0.025, errors_s
    assert sorted(abs(error) for error in errors_s)[len(errors_s) * 9 // 10] < 0.010, errors_s


@pytest.mark.process
def test_a_bad_recorder_configuration_ends_it_with_one_line_naming_the_problem(tmp_path):
    (tmp_path / 'taken').mkdir()
    for parameters, complaint in [(['flush_period:=0.0'], 'flush_period'),
                                  (['topics:=5'], 'parameter topics must be a list'),
                                  ([], 'parameter output: cannot create bag .*exists already')]:
        with NodeProcess(RECORDER, recorder_args(tmp_path / 'taken', *parameters)) as recorder:
            assert recorder.wait(timeout_s=60) == 1
        assert re.search(rf'\[FATAL\] .*{complaint}', recorder.output), recorder.output
        assert 'Traceback' not in recorder.output


def test_the_graph_gives_each_publishers_offered_qos_for_the_recording(ros_context):
    node = Node('probe', context=ros_context)
    node.create_publisher(HasCommand, 'latched', QoSProfile(
        depth=7, reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.create_publisher(HasCommand, 'everything', QoSProfile(
        history=HistoryPolicy.KEEP_ALL, depth=1))
    deadline = time.monotonic() + 10
    while not node.get_publishers_info_by_topic('latched') and time.monotonic() < deadline:
        time.sleep(0.05)
    (latched,) = node.get_publishers_info_by_topic('latched')
    assert latched.topic_type == COMMAND
    qos = offered_qos(latched.qos_profile)
    assert (qos.reliability, qos.durability) == (QosReliability.BEST_EFFORT,
                                                 QosDurability.TRANSIENT_LOCAL)
    choice = subscription_qos([latched.qos_profile])
    assert choice.transient_local and not choice.reliable
    (everything,) = node.get_publishers_info_by_topic('/everything')
    assert offered_qos(everything.qos_profile).reliability == QosReliability.RELIABLE
    node.destroy_node()


@pytest.mark.process
def test_replay_of_a_bag_whose_types_are_unknown_here_fails_naming_them(tmp_path, monkeypatch):
    share = tmp_path / 'prefix' / 'share' / 'vendor_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'Pump.msg').write_text('float64 speed  # [rad/s]\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'prefix'))
    with BagWriter(tmp_path / 'bag') as writer:  # a bag from a robot with more packages
        writer.add_topic('/pump', 'vendor_msgs/msg/Pump')
        writer.write('/pump', 0, b'\x00\x01\x00\x00' + bytes(8))
    monkeypatch.undo()
    with NodeProcess(REPLAY, [str(tmp_path / 'bag')]) as replay:
        assert replay.wait(timeout_s=60) == 1
    assert "not replaying /pump: message type 'vendor_msgs/msg/Pump' is unknown here" \
        in replay.output
    assert re.search(r'\[FATAL\] .*none of the topics of .*bag can be published here',
                     replay.output), replay.output


LISTENER = """
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState
rclpy.init()
node = Node('frozen_listener')
node.create_subscription(JointState, '/joint_reference', lambda m: print('got', flush=True), 10)
rclpy.spin(node)
"""


@pytest.mark.process
def test_a_replay_waits_for_its_subscribers_acknowledgements_and_names_a_topic_left_waiting(
        tmp_path):
    source = tmp_path / 'source'
    with BagWriter(source) as writer:
        writer.add_topic('/joint_reference', JOINTS, [offered_qos(RELIABLE)])
        for i in range(20):
            writer.write('/joint_reference', 1_700_000_000_000_000_000 + i * 50_000_000,
                         serialize_message(JointState(position=[float(i)])))
    listener = subprocess.Popen(tethered([sys.executable, '-c', LISTENER]), stdout=subprocess.PIPE,
                                text=True, cwd=tmp_path)
    try:
        with NodeProcess(REPLAY, [str(source), '--wait-for-subscribers']) as replay:
            assert listener.stdout is not None
            assert listener.stdout.readline() == 'got\n'
            # Frozen, the listener's DDS threads acknowledge nothing more.
            listener.send_signal(signal.SIGSTOP)
            frozen = time.monotonic()
            assert replay.wait(timeout_s=60) == 0
            ended = time.monotonic() - frozen
        assert 'replayed 20 messages' in replay.output
        assert re.search(r'not acknowledged within 2 s on /joint_reference', replay.output), \
            replay.output
        assert ended >= 2.0  # the wait for acknowledgements, then an end
    finally:
        listener.send_signal(signal.SIGCONT)
        listener.kill()
        listener.wait()

import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import String

from exo_has_runtime.polling import INBOX_SUFFIX, Inbox

QOS = QoSProfile(depth=100)


def wait_for(condition, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, 'timed out'
        time.sleep(0.01)


@pytest.fixture
def owner(ros_context):
    node = Node('polling_owner', namespace='/ns', context=ros_context)
    yield node
    node.destroy_node()


def test_an_inbox_takes_every_message_of_its_topics_in_the_order_they_arrived(owner):
    inbox = Inbox(owner)
    assert inbox.node_name == 'polling_owner' + INBOX_SUFFIX
    a = owner.create_publisher(String, '/a', QOS)
    b = owner.create_publisher(String, '/b', QOS)
    inbox.subscribe('a', String, '/a', QOS)
    inbox.subscribe('b', String, '/b', QOS, raw=True)
    wait_for(lambda: a.get_subscription_count() and b.get_subscription_count())
    before = time.time_ns()
    for i in range(20):
        (a if i % 2 else b).publish(String(data=str(i)))
        time.sleep(0.002)
    taken = []
    wait_for(lambda: taken.extend(inbox.drain()) or len(taken) == 20)
    stamps = [t.received_ns for t in taken]
    assert stamps == sorted(stamps) and before <= stamps[0] <= stamps[-1] <= time.time_ns()
    assert [t.topic for t in taken] == ['b', 'a'] * 10
    assert [t.data.data for t in taken if t.topic == 'a'] == [str(i) for i in range(1, 20, 2)]
    assert all(isinstance(t.data, bytes) for t in taken if t.topic == 'b')
    assert inbox.drain() == []
    inbox.destroy()


def test_unsubscribing_returns_what_was_still_queued_and_a_second_subscription_is_refused(owner):
    inbox = Inbox(owner)
    a = owner.create_publisher(String, '/a', QOS)
    inbox.subscribe('a', String, '/a', QOS)
    with pytest.raises(ValueError, match='a is subscribed already'):
        inbox.subscribe('a', String, '/a', QOS)
    wait_for(lambda: a.get_subscription_count())
    a.publish(String(data='left'))
    time.sleep(0.2)
    assert [t.data.data for t in inbox.unsubscribe('a')] == ['left']
    assert inbox.drain() == []
    inbox.destroy()


def test_the_inbox_node_keeps_its_own_name_when_the_command_line_renames_the_node():
    context = Context()
    rclpy.init(args=['--ros-args', '-r', '__node:=renamed'], context=context)
    try:
        node = Node('owner', context=context)
        inbox = Inbox(node)
        # Had the inbox taken the global remap, two nodes would be called renamed.
        assert node.get_name() == 'renamed' and inbox.node_name == 'renamed' + INBOX_SUFFIX
        inbox.destroy()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)

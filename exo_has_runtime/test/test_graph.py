"""PublisherWatch: the publishers of a topic by node name, an unnamed one held back a moment.

And how long a census of a domain listens.
"""

from types import SimpleNamespace

import pytest

from exo_has_runtime.dds import localhost_profile, write_profile
from exo_has_runtime.graph import (
    CENSUS_MARGIN,
    UNKNOWN_NODE_NAME,
    UNNAMED_WAIT_S,
    PublisherWatch,
    census_time,
)

TOPIC = '/left_hip/has_command'


class FakeNode:
    """A node's view of the graph: the publishers of each topic, set by the test."""

    def __init__(self) -> None:
        self.publishers: list[SimpleNamespace] = []

    def resolve_topic_name(self, topic: str) -> str:
        """Return the topic as given (absolute already)."""
        return topic

    def get_fully_qualified_name(self) -> str:
        """Return the node's own name, whose publishers the watch leaves out."""
        return '/driver'

    def get_publishers_info_by_topic(self, topic: str) -> list[SimpleNamespace]:
        """Return the publishers the test set, whatever the topic."""
        return list(self.publishers)


def publisher(name: str, gid: int) -> SimpleNamespace:
    """Return a publisher's endpoint info as rclpy gives it (the fields the watch reads)."""
    return SimpleNamespace(node_name=name, node_namespace='/', endpoint_gid=[gid] * 16)


def test_a_lone_unnamed_publisher_beside_the_source_itself_is_held_back_until_named():
    node = FakeNode()
    watch = PublisherWatch(node, [TOPIC], source=True)  # the node is the topic's one source
    node.publishers = [publisher('driver', 1), publisher(UNKNOWN_NODE_NAME, 2)]
    assert watch.poll(0.0) == {}  # held back: its name comes on ros_discovery_info
    node.publishers[1] = publisher('robot_graph', 2)
    assert watch.poll(0.1) == {TOPIC: ['/robot_graph']}


def test_an_unnamed_publisher_is_reported_as_it_is_once_the_wait_is_over():
    node = FakeNode()
    watch = PublisherWatch(node, [TOPIC], source=True)
    node.publishers = [publisher(UNKNOWN_NODE_NAME, 2)]
    assert watch.poll(0.0) == {}
    [name] = watch.poll(UNNAMED_WAIT_S + 0.01)[TOPIC]
    assert name.startswith('an unnamed node (publisher gid 0202')


def test_where_the_node_is_not_the_source_one_unnamed_publisher_is_judged_at_once():
    node = FakeNode()
    watch = PublisherWatch(node, [TOPIC])  # a watchdog: one publisher is the one allowed
    node.publishers = [publisher(UNKNOWN_NODE_NAME, 2)]
    assert list(watch.poll(0.0)) == [TOPIC]
    node.publishers.append(publisher('controller', 3))
    assert watch.poll(0.1) == {}  # two, one unnamed: held back
    assert watch.poll(0.1 + UNNAMED_WAIT_S + 0.01)[TOPIC][1] == '/controller'


@pytest.mark.parametrize(('period', 'listened'), [(0.5, 2.0), (None, 4.5)])
def test_a_census_listens_one_announcement_period_and_its_margin(monkeypatch, tmp_path, period,
                                                                 listened):
    profile = write_profile(localhost_profile(announcement_period=period), tmp_path)
    monkeypatch.setenv('FASTRTPS_DEFAULT_PROFILES_FILE', str(profile))
    assert census_time() == pytest.approx(listened)
    assert census_time() == pytest.approx((period or 3.0) + CENSUS_MARGIN)

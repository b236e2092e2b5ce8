"""What a node sees of the ROS graph: who else is on a domain, who publishes on a topic.

:func:`nodes_on_domain` lists the nodes a short-lived participant discovers on a domain (a
session refuses a domain where another runs). :class:`PublisherWatch` names the publishers of
some topics as a running node sees them (the watchdog and the driver look for a second source
of a joint's states or commands).
"""

from __future__ import annotations

import time
from collections.abc import Collection, Sequence

from rclpy.context import Context
from rclpy.node import Node
from rclpy.topic_endpoint_info import TopicEndpointInfo

from exo_has_runtime.dds import announcement_period

#: How long a newcomer listens for the nodes already on a domain beyond one announcement
#: period of their participants [s]. A newcomer that misses its first exchange with a
#: participant waits for that one's next announcement; ROS 2 carries the node names on
#: ros_discovery_info, which needs the endpoints discovered too, and a busy machine slows both.
CENSUS_MARGIN = 1.5

#: How long to listen on once a wanted node was seen, for the others [s].
CENSUS_LINGER = 1.0

#: How often the graph is read meanwhile [s].
CENSUS_POLL = 0.1


def census_time() -> float:
    """Return how long a census listens [s]: an announcement period and :data:`CENSUS_MARGIN`.

    The period of this process's discovery settings
    (:func:`exo_has_runtime.dds.announcement_period`): 2 s on the LOCALHOST profile, 4.5 s on
    Fast DDS's own 3 s.
    """
    return announcement_period() + CENSUS_MARGIN


def nodes_on_domain(domain_id: int | None = None, listen_s: float | None = None,
                    wanted: set[str] | None = None) -> list[str]:
    """Return the full names of the nodes seen on a domain, sorted.

    Parameters
    ----------
    domain_id : int or None
        ROS domain; ``ROS_DOMAIN_ID`` (or 0) by default.
    listen_s : float or None
        How long to listen [s]; :func:`census_time` by default.
    wanted : set[str] or None
        Full node names (``/name``): once one of them is seen, the listening ends
        :data:`CENSUS_LINGER` seconds later.

    """
    context = Context()
    context.init([], domain_id=domain_id)
    try:
        node = Node('exo_has_census', context=context, enable_rosout=False,
                    start_parameter_services=False)
        me = node.get_fully_qualified_name()
        seen: set[str] = set()
        deadline = time.monotonic() + (census_time() if listen_s is None else listen_s)
        while time.monotonic() < deadline:
            seen = {f'{namespace.rstrip("/")}/{name}'
                    for name, namespace in node.get_node_names_and_namespaces()} - {me}
            if wanted and seen & wanted:  # listen a little more for a fuller list
                deadline = min(deadline, time.monotonic() + CENSUS_LINGER)
                wanted = None
            time.sleep(CENSUS_POLL)
        node.destroy_node()  # type: ignore[no-untyped-call]  # rclpy 7.1.6: untyped
        return sorted(seen)
    finally:
        context.try_shutdown()


#: What rmw reports as the node of an endpoint whose node it does not know yet.
UNKNOWN_NODE_NAME = '_NODE_NAME_UNKNOWN_'

#: How long a publisher may stay unnamed beside another before it is reported as it is [s].
UNNAMED_WAIT_S = 0.3


def publisher_name(info: TopicEndpointInfo) -> str:
    """Return a publisher's node's full name, or its GID while ROS does not know the node."""
    if info.node_name == UNKNOWN_NODE_NAME:
        return f'an unnamed node (publisher gid {bytes(info.endpoint_gid[:12]).hex()})'
    return f'{info.node_namespace.rstrip("/")}/{info.node_name}'


class PublisherWatch:
    """The publishers of some topics, by node name, as a node's view of the graph shows them.

    DDS discovery shows a publisher before ROS names its node (the names come on
    ros_discovery_info): a topic where an unnamed publisher stands beside another is held back
    for up to :data:`UNNAMED_WAIT_S`, so that what is reported names it.

    Parameters
    ----------
    node : Node
        The node whose view is read; its own publishers are left out.
    topics : Sequence[str]
        Topics to watch (relative names are resolved as the node resolves them).
    ignore : Collection[str]
        Full names of other nodes whose publishers are left out (``/watchdog``).
    source : bool
        Whether the node is itself the topics' one source (the driver of the states it
        publishes): then an unnamed publisher alone stands beside it and is held back too.
        Reported at once, a stray commander came out as "an unnamed node" where its name
        followed a moment later.

    """

    def __init__(self, node: Node, topics: Sequence[str], ignore: Collection[str] = (),
                 source: bool = False) -> None:
        self._node = node
        self.topics = tuple(node.resolve_topic_name(topic) for topic in topics)
        self._ignore = {node.get_fully_qualified_name(), *ignore}
        self._beside = 0 if source else 1  # other publishers that a second one stands beside
        self._unnamed_since: dict[str, float] = {}

    def poll(self, now_s: float) -> dict[str, list[str]]:
        """Return the names of each topic's publishers, for the topics ready to be judged.

        Parameters
        ----------
        now_s : float
            Time now [s], on any clock that the calls share.

        """
        found: dict[str, list[str]] = {}
        for topic in self.topics:
            named = [(publisher_name(info), info.node_name == UNKNOWN_NODE_NAME)
                     for info in self._node.get_publishers_info_by_topic(topic)]
            named = [(name, unknown) for name, unknown in named if name not in self._ignore]
            names = [name for name, _ in named]
            if len(names) > self._beside and any(unknown for _, unknown in named):
                since = self._unnamed_since.setdefault(topic, now_s)
                if now_s - since < UNNAMED_WAIT_S:
                    continue
            self._unnamed_since.pop(topic, None)
            found[topic] = names
        return found

"""Who else is on a ROS domain: the nodes a short-lived participant discovers there."""

from __future__ import annotations

import time

from rclpy.context import Context
from rclpy.node import Node

#: How long a newcomer listens for the nodes already on a domain [s]. ROS 2 carries node names
#: on ros_discovery_info, which needs the endpoints discovered first: on the 2-vCPU test VM,
#: with a session running, that took from under one to about three seconds.
CENSUS_TIME = 4.0

#: How long to listen on once a wanted node was seen, for the others [s].
CENSUS_LINGER = 1.0

#: How often the graph is read meanwhile [s].
CENSUS_POLL = 0.1


def nodes_on_domain(domain_id: int | None = None, listen_s: float = CENSUS_TIME,
                    wanted: set[str] | None = None) -> list[str]:
    """Return the full names of the nodes seen on a domain, sorted.

    Parameters
    ----------
    domain_id : int or None
        ROS domain; ``ROS_DOMAIN_ID`` (or 0) by default.
    listen_s : float
        How long to listen [s].
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
        deadline = time.monotonic() + listen_s
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

"""QoS profiles that publishers and subscribers of a topic must agree on, shared by every node.

Built from the seam's QoS classes: rclpy's on a robot, the standalone backend's elsewhere.
"""

from __future__ import annotations

from exo_has_runtime import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from exo_has_runtime.topics import SAFETY_EVENT_DEPTH

#: ``safety_events``: reliable and transient local, so that a node started later (a controller,
#: a recorder) still learns of a latched stop.
SAFETY_EVENT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAFETY_EVENT_DEPTH,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)

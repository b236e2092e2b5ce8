"""QoS profiles that publishers and subscribers of a topic must agree on, shared by every node."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from exo_has_common.topics import SAFETY_EVENT_DEPTH

#: ``safety_events``: reliable and transient local, so that a node started later (a controller,
#: a recorder) still learns of a latched stop.
SAFETY_EVENT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAFETY_EVENT_DEPTH,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Sensor-data topics (best effort, volatile) read by a node that must see every sample, such as
#: the watchdog: deep enough for a second of a 200 Hz topic, so that a process that stalled still
#: sees each sample once it runs again. Matches publishers of ``qos_profile_sensor_data``.
DEEP_SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200,
                             reliability=ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.VOLATILE)

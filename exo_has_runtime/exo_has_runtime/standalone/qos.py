"""ROS 2 quality-of-service profiles and their mapping to Cyclone DDS, as rmw_cyclonedds_cpp does.

The classes mirror ``rclpy.qos``; :func:`dds_qos` follows ``create_readwrite_qos`` of
rmw_cyclonedds_cpp (Jazzy): depth 0 means keep-last 1, RELIABLE blocks without limit,
TRANSIENT_LOCAL gets a durability service with the same history, unspecified deadline and
lifespan are left unset, autodispose is off, and the data representation is XCDR1 only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from cyclonedds.qos import Policy, Qos

from exo_has_runtime.standalone.clock import Duration

_INFINITE_NS = 0x7FFFFFFFFFFFFFFF


class HistoryPolicy(IntEnum):
    """History policy, numbered as rmw."""

    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2
    UNKNOWN = 3


class ReliabilityPolicy(IntEnum):
    """Reliability policy, numbered as rmw."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2
    UNKNOWN = 3
    BEST_AVAILABLE = 4


class DurabilityPolicy(IntEnum):
    """Durability policy, numbered as rmw."""

    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2
    UNKNOWN = 3
    BEST_AVAILABLE = 4


class LivelinessPolicy(IntEnum):
    """Liveliness policy, numbered as rmw."""

    SYSTEM_DEFAULT = 0
    AUTOMATIC = 1
    MANUAL_BY_TOPIC = 3
    UNKNOWN = 4
    BEST_AVAILABLE = 5


def _unspecified() -> Duration:
    return Duration()


@dataclass
class QoSProfile:
    """A ROS 2 QoS profile, as ``rclpy.qos.QoSProfile``.

    Durations of zero mean "unspecified" (the rmw default), as in rclpy.
    """

    history: HistoryPolicy = HistoryPolicy.KEEP_LAST
    depth: int = 10
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    durability: DurabilityPolicy = DurabilityPolicy.VOLATILE
    deadline: Duration = field(default_factory=_unspecified)
    lifespan: Duration = field(default_factory=_unspecified)
    liveliness: LivelinessPolicy = LivelinessPolicy.SYSTEM_DEFAULT
    liveliness_lease_duration: Duration = field(default_factory=_unspecified)
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        if self.depth < 0:
            msg = f'QoS depth must be non-negative, got {self.depth}'
            raise ValueError(msg)
        for policy in (self.reliability, self.durability):
            if policy.name in ('UNKNOWN', 'BEST_AVAILABLE'):
                msg = f'QoS policy {policy!r} is not supported by the standalone backend'
                raise ValueError(msg)


def qos_from_depth(qos: QoSProfile | int) -> QoSProfile:
    """Accept a profile or a depth, as create_publisher and create_subscription do."""
    if isinstance(qos, QoSProfile):
        return qos
    if isinstance(qos, int) and not isinstance(qos, bool):
        return QoSProfile(depth=qos)
    msg = f'expected a QoSProfile or a history depth, got {qos!r}'
    raise TypeError(msg)


#: rmw_qos_profile_sensor_data: best effort, volatile, keep last 5.
qos_profile_sensor_data = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
#: rmw_qos_profile_default: reliable, volatile, keep last 10.
qos_profile_system_default = QoSProfile(
    history=HistoryPolicy.SYSTEM_DEFAULT, depth=0,
    reliability=ReliabilityPolicy.SYSTEM_DEFAULT, durability=DurabilityPolicy.SYSTEM_DEFAULT)
#: rmw_qos_profile_services_default: reliable, volatile, keep last 10.
qos_profile_services_default = QoSProfile(depth=10)
#: rmw_qos_profile_parameters: reliable, volatile, keep last 1000.
qos_profile_parameters = QoSProfile(depth=1000)
#: rmw_qos_profile_parameter_events: reliable, volatile, keep last 1000.
qos_profile_parameter_events = QoSProfile(depth=1000)


def dds_qos(profile: QoSProfile, user_data: bytes = b'') -> Qos:
    """Return the Cyclone DDS QoS of a ROS 2 reader or writer with this profile.

    Parameters
    ----------
    profile : QoSProfile
        The ROS 2 profile.
    user_data : bytes
        USER_DATA of the endpoint (``typehash=RIHS01_...;`` for topics).

    Returns
    -------
    Qos
        The policies rmw_cyclonedds_cpp would set.

    """
    policies: list[object] = [Policy.WriterDataLifecycle(autodispose=False)]
    if profile.history == HistoryPolicy.KEEP_ALL:
        history: object = Policy.History.KeepAll
    else:
        history = Policy.History.KeepLast(max(profile.depth, 1))
    policies.append(history)
    if profile.reliability == ReliabilityPolicy.BEST_EFFORT:
        policies.append(Policy.Reliability.BestEffort)
    else:
        policies.append(Policy.Reliability.Reliable(max_blocking_time=_INFINITE_NS))
    if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        policies.append(Policy.Durability.TransientLocal)
        policies.append(Policy.DurabilityService(
            cleanup_delay=0, history=history, max_samples=-1, max_instances=-1,
            max_samples_per_instance=-1))
    else:
        policies.append(Policy.Durability.Volatile)
    if profile.lifespan.nanoseconds:
        policies.append(Policy.Lifespan(profile.lifespan.nanoseconds))
    if profile.deadline.nanoseconds:
        policies.append(Policy.Deadline(profile.deadline.nanoseconds))
    lease = profile.liveliness_lease_duration.nanoseconds or _INFINITE_NS
    if profile.liveliness == LivelinessPolicy.MANUAL_BY_TOPIC:
        policies.append(Policy.Liveliness.ManualByTopic(lease))
    else:
        policies.append(Policy.Liveliness.Automatic(lease))
    policies.append(Policy.DataRepresentation(use_cdrv0_representation=True))
    if user_data:
        policies.append(Policy.Userdata(user_data))
    return Qos(*policies)


def profile_from_dds(qos: Qos) -> QoSProfile:
    """Return the ROS 2 profile of a discovered reader or writer, the inverse of :func:`dds_qos`.

    Policies the endpoint does not carry keep rmw's defaults (reliable, volatile, keep last 10
    for a missing history); an infinite deadline, lifespan or lease reads as unspecified.
    """
    profile = QoSProfile()
    history = qos[Policy.History] if Policy.History in qos else None
    if history == Policy.History.KeepAll:
        profile.history, profile.depth = HistoryPolicy.KEEP_ALL, 0
    elif history is not None:
        profile.depth = int(history.depth)
    if Policy.Reliability in qos and qos[Policy.Reliability] == Policy.Reliability.BestEffort:
        profile.reliability = ReliabilityPolicy.BEST_EFFORT
    if Policy.Durability in qos and qos[Policy.Durability] != Policy.Durability.Volatile:
        # Transient and persistent are stronger than any ROS 2 endpoint asks for.
        profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
    if Policy.Deadline in qos:
        profile.deadline = _finite(int(qos[Policy.Deadline].deadline))
    if Policy.Lifespan in qos:
        profile.lifespan = _finite(int(qos[Policy.Lifespan].lifespan))
    if Policy.Liveliness in qos:
        liveliness = qos[Policy.Liveliness]
        profile.liveliness = LivelinessPolicy.MANUAL_BY_TOPIC \
            if isinstance(liveliness, Policy.Liveliness.ManualByTopic) \
            else LivelinessPolicy.AUTOMATIC
        profile.liveliness_lease_duration = _finite(int(liveliness.lease_duration))
    return profile


def _finite(nanoseconds: int) -> Duration:
    return Duration(nanoseconds=0 if nanoseconds >= _INFINITE_NS else nanoseconds)

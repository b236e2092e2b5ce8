"""The QoS a bag records for each topic: what its publishers offered, in rosbag2's form.

rosbag2 keeps each topic's offered profiles twice: in its MCAP channel's metadata
(``offered_qos_profiles``, a YAML text) and in ``metadata.yaml``; version 9 writes them as a
list with the policies by name (``reliable``, ``transient_local``, ...).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from enum import Enum
from typing import TYPE_CHECKING, Protocol, TypeVar

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos

if TYPE_CHECKING:
    from rosbags.rosbag2.metadata import QosDict

__all__ = ['QosProfileLike', 'offered_qos', 'parse_qos', 'qos_dicts', 'qos_yaml']

_Policy = TypeVar('_Policy', bound=Enum)


class _DurationLike(Protocol):
    @property
    def nanoseconds(self) -> int: ...


class OfferedProfile(Protocol):
    """What a bag and the recorder (:mod:`exo_has_runtime.recording`) read of a ``QoSProfile``."""

    @property
    def history(self) -> int: ...

    @property
    def depth(self) -> int: ...

    @property
    def reliability(self) -> int: ...

    @property
    def durability(self) -> int: ...


class QosProfileLike(OfferedProfile, Protocol):
    """What :func:`offered_qos` reads of an rclpy ``QoSProfile``."""

    @property
    def deadline(self) -> _DurationLike: ...  # noqa: D102

    @property
    def lifespan(self) -> _DurationLike: ...  # noqa: D102

    @property
    def liveliness(self) -> int: ...  # noqa: D102

    @property
    def liveliness_lease_duration(self) -> _DurationLike: ...  # noqa: D102

    @property
    def avoid_ros_namespace_conventions(self) -> bool: ...  # noqa: D102


def _policy(kind: type[_Policy], value: int) -> _Policy:
    """Return a policy by rmw's number; one rosbags does not know is ``UNKNOWN``."""
    try:
        return kind(int(value))
    except ValueError:
        return kind['UNKNOWN']


def offered_qos(profile: QosProfileLike) -> Qos:
    """Return a ROS 2 QoS profile (as the graph reports a publisher's) as a bag records it.

    The policies are numbered alike in rmw, rclpy and rosbags; infinite durations (rmw's
    ``RMW_DURATION_INFINITE``) stay as their largest value, as rosbag2 writes them.
    """
    def time_of(duration: _DurationLike) -> QosTime:
        seconds, nanoseconds = divmod(int(duration.nanoseconds), 1_000_000_000)
        return QosTime(seconds, nanoseconds)

    return Qos(_policy(QosHistory, profile.history), int(profile.depth),
               _policy(QosReliability, profile.reliability),
               _policy(QosDurability, profile.durability),
               time_of(profile.deadline), time_of(profile.lifespan),
               _policy(QosLiveliness, profile.liveliness),
               time_of(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def qos_dicts(profiles: Iterable[Qos]) -> list[QosDict]:
    """Return profiles as ``metadata.yaml`` version 9 lists them."""
    return dump_qos_v9(list(profiles))


def qos_yaml(profiles: Sequence[Qos]) -> str:
    """Return profiles as the YAML text of an MCAP channel's ``offered_qos_profiles``."""
    text: str = yaml.safe_dump(qos_dicts(profiles), default_flow_style=False, sort_keys=False)
    return text.strip()

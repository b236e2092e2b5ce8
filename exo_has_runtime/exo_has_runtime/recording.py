"""What the recorder records and how, and how a replay is timed: the ROS-free decisions.

QoS, as rosbag2 adapts it (``ros2 bag record`` and ``play``): a subscription that asks for more
than a publisher offers does not match it (a reliable reader never hears a best-effort writer, a
transient-local reader never a volatile one), so the recorder asks for reliable only when every
publisher on the topic offers it, and for transient local (to receive the history a latched
topic such as ``safety_events`` kept from before the recorder started) only when every one
does; sensor-data topics, published best effort, are thus recorded best effort. Its history is
deep (:data:`RECORD_DEPTH`, or more if a transient-local publisher keeps more) so that a burst
while the recorder is busy is not overwritten unread. Replay offers what was recorded: reliable
and transient local when every recorded publisher offered it, with their deepest history where
the graph told it (rmw_fastrtps_cpp reports a publisher's history as unknown, depth 0: then
:data:`DEFAULT_REPLAY_DEPTH`).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosReliability

from exo_has_common.bags.qos import OfferedProfile
from exo_has_runtime.errors import ReplayError

#: Where bags go when the recorder is given no output (nodes run from a temporary folder, so
#: the working directory is no place for them).
DEFAULT_BAG_ROOT = Path('~/.ros/exo_has_bags')

#: Topics never recorded unless asked for by name: rmw_dds_common's graph information.
EXCLUDED_TOPICS = frozenset({'/ros_discovery_info'})

#: History depth of the recorder's subscriptions.
RECORD_DEPTH = 1000

#: QoS of a replayed topic whose bag recorded none: rclpy's default (reliable, volatile, 10).
DEFAULT_REPLAY_DEPTH = 10

# rmw's numbering of the policies (rclpy's IntEnums).
_RELIABLE = 1
_TRANSIENT_LOCAL = 1


@dataclass(frozen=True)
class QosChoice:
    """The QoS of a subscription or publisher, reduced to what the choice above sets."""

    reliable: bool
    transient_local: bool
    depth: int


def bag_path(output: str, now: datetime) -> Path:
    """Return the absolute bag directory for the recorder's ``output`` parameter.

    Parameters
    ----------
    output : str
        The parameter: a directory to create, ``~`` expanded, relative to the working
        directory; empty for ``~/.ros/exo_has_bags/session_<YYYYmmdd_HHMMSS>``.
    now : datetime
        Local time of the start of the recording.

    """
    if not output.strip():
        return (DEFAULT_BAG_ROOT / f'session_{now:%Y%m%d_%H%M%S}').expanduser()
    return Path(output).expanduser().absolute()


def is_hidden(topic: str) -> bool:
    """Whether a topic is hidden (a name token starting with ``_``), as ROS 2 defines it."""
    return any(token.startswith('_') for token in topic.split('/'))


def topics_to_record(graph: Sequence[tuple[str, Sequence[str]]], wanted: Collection[str] | None,
                     recording: Collection[str]
                     ) -> tuple[list[tuple[str, str]], list[tuple[str, list[str]]]]:
    """Choose the topics of the graph to start recording.

    Parameters
    ----------
    graph : Sequence[tuple[str, Sequence[str]]]
        Topics and their types, as ``get_topic_names_and_types()`` gives them.
    wanted : Collection[str] or None
        Fully qualified topics to record; None for every topic but the hidden ones and
        :data:`EXCLUDED_TOPICS`.
    recording : Collection[str]
        Topics recorded already.

    Returns
    -------
    tuple[list[tuple[str, str]], list[tuple[str, list[str]]]]
        The new topics with their type, then the topics left out because the graph shows them
        with several types (a bag topic has one).

    """
    chosen, ambiguous = [], []
    for topic, types in graph:
        if topic in recording:
            continue
        if wanted is not None and topic not in wanted:
            continue
        if wanted is None and (topic in EXCLUDED_TOPICS or is_hidden(topic)):
            continue
        if len(types) == 1:
            chosen.append((topic, types[0]))
        elif types:
            ambiguous.append((topic, sorted(types)))
    return chosen, ambiguous


def subscription_qos(offers: Sequence[OfferedProfile]) -> QosChoice:
    """Return the QoS the recorder subscribes with to a topic, from its publishers' offers.

    Reliable if every publisher offers reliable, transient local if every one offers it (a
    topic without publishers: best effort, volatile); history :data:`RECORD_DEPTH` deep, or
    as deep as the deepest transient-local publisher's.
    """
    reliable = bool(offers) and all(int(o.reliability) == _RELIABLE for o in offers)
    latched = bool(offers) and all(int(o.durability) == _TRANSIENT_LOCAL for o in offers)
    depth = max([RECORD_DEPTH, *(int(o.depth) for o in offers if latched)])
    return QosChoice(reliable, latched, depth)


def weakened_qos(current: QosChoice, offers: Sequence[OfferedProfile]) -> QosChoice | None:
    """Return the weaker QoS a recording subscription needs to hear every publisher, if any.

    A publisher that joined later may offer less than the subscription asks for (best effort
    to a reliable one, volatile to a transient-local one): it would go unrecorded. The result
    asks for no more than every publisher offers; None when the current QoS hears them all.
    The QoS is never made stronger again, so that the subscription does not come and go.
    """
    offered = subscription_qos(offers) if offers else current
    weaker = QosChoice(current.reliable and offered.reliable,
                       current.transient_local and offered.transient_local, current.depth)
    return weaker if weaker != current else None


def replay_qos(recorded: Sequence[Qos]) -> QosChoice:
    """Return the QoS a replay publishes a topic with, from the offers its bag recorded.

    Reliable and transient local when every recorded publisher offered them, with the
    deepest keep-last history recorded (:data:`DEFAULT_REPLAY_DEPTH` where none is known);
    without a record, reliable, volatile, depth :data:`DEFAULT_REPLAY_DEPTH`.
    """
    if not recorded:
        return QosChoice(True, False, DEFAULT_REPLAY_DEPTH)
    reliable = all(q.reliability == QosReliability.RELIABLE for q in recorded)
    latched = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in recorded)
    depths = [q.depth for q in recorded if q.history == QosHistory.KEEP_LAST and q.depth > 0]
    return QosChoice(reliable, latched, max(depths, default=DEFAULT_REPLAY_DEPTH))


def check_rate(rate: float) -> float:
    """Return a replay rate factor if it is positive and finite.

    Raises
    ------
    ReplayError
        Naming the rate otherwise.

    """
    if not math.isfinite(rate) or rate <= 0.0:
        msg = f'the replay rate must be a positive factor (1 is real time), got {rate}'
        raise ReplayError(msg)
    return rate


def select_replay_topics(available: Mapping[str, str],
                         wanted: Sequence[str] | None) -> list[str]:
    """Return the bag topics to replay, sorted.

    Parameters
    ----------
    available : Mapping[str, str]
        The bag's topics and types.
    wanted : Sequence[str] or None
        Topics asked for (None: all); a name without a leading ``/`` means the absolute one.

    Raises
    ------
    ReplayError
        Naming the topics the bag does not have, and those it has.

    """
    if not wanted:
        return sorted(available)
    absolute = ['/' + topic.lstrip('/') for topic in wanted]
    unknown = [topic for topic in absolute if topic not in available]
    if unknown:
        msg = (f'the bag has no topic {", ".join(unknown)}; its topics: '
               f'{", ".join(sorted(available)) or "none"}')
        raise ReplayError(msg)
    return sorted(set(absolute))


def replay_offset_ns(timestamp_ns: int, first_ns: int, rate: float) -> int:
    """Return when to publish a message, after the replay's start [ns].

    The bag's time since its first replayed message, divided by the rate factor.
    """
    return round((timestamp_ns - first_ns) / rate)

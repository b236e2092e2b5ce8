"""Reading bags: their topics, their messages in time order, and a summary of both.

rosbags' rosbag2 ``Reader`` reads the bag (``metadata.yaml`` and the MCAP file's summary). A
bag without ``metadata.yaml`` was never closed: it is refused with the command that recovers it
(:func:`exo_has_common.bags.recovery.recover_bag`).
"""

from __future__ import annotations

import struct
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.typesys import TypesysError, get_types_from_idl, get_types_from_msg
from rosbags.typesys.store import Typestore

from exo_has_common.bags.definitions import default_typestore
from exo_has_common.bags.gaps import Gap, GapFinder
from exo_has_common.errors import BagError, BagNotFoundError, MalformedBagError, UnfinishedBagError


class BagMessage(NamedTuple):
    """One message of a bag."""

    topic: str
    msgtype: str
    timestamp_ns: int
    data: bytes


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag: its type, message count, and the QoS its publishers offered."""

    topic: str
    msgtype: str
    count: int
    offered_qos: tuple[Qos, ...]


def _recover_hint(path: Path) -> str:
    return (f'if its recorder was killed, `exo-has bag recover {path}` rewrites it with every '
            'message up to its last complete chunk')


@contextmanager
def _open_reader(path: str | Path) -> Iterator[Reader]:
    bag = Path(path).expanduser()
    if not bag.exists():
        msg = f'no bag at {bag}'
        raise BagNotFoundError(msg)
    if bag.is_dir() and not (bag / 'metadata.yaml').is_file():
        if any(bag.glob('*.mcap')):
            msg = (f'bag {bag} has no metadata.yaml: it was never closed; '
                   f'{_recover_hint(bag)}')
            raise UnfinishedBagError(msg)
        msg = f'{bag} is not a rosbag2 bag: it holds neither metadata.yaml nor an .mcap file'
        raise MalformedBagError(msg)
    try:
        reader = Reader(bag)
        reader.open()
    except (ReaderError, KeyError, ValueError, OSError) as exc:
        msg = f'cannot read bag {bag}: {exc}; {_recover_hint(bag)}'
        raise MalformedBagError(msg) from exc
    try:
        yield reader
    finally:
        reader.close()


def bag_topics(path: str | Path) -> list[BagTopic]:
    """Return the topics of a bag, from its metadata, sorted by name.

    Raises
    ------
    BagNotFoundError
        If there is no bag at the path.
    UnfinishedBagError
        If the bag was never closed (naming the command that recovers it).
    MalformedBagError
        If the files are not a readable bag.

    """
    with _open_reader(path) as reader:
        return sorted((BagTopic(connection.topic, connection.msgtype, connection.msgcount,
                                tuple(_qos_of(connection)))
                       for connection in reader.connections), key=lambda t: t.topic)


def bag_typestore(path: str | Path, base: Typestore | None = None) -> Typestore:
    """Return a typestore that reads a bag's messages, from the bag's own definitions if need be.

    ``base`` (default: :func:`~exo_has_common.bags.definitions.default_typestore`) where it knows
    every type of the bag; else a copy of it with the types it lacks taken from the definitions
    the bag embeds (rosbag2 and :class:`~exo_has_common.bags.writer.BagWriter` embed each
    topic's): a machine without the workspace (the diagnosis installed by pip) reads the
    exo_has_msgs types of our own sessions so.

    Raises
    ------
    BagNotFoundError, UnfinishedBagError, MalformedBagError
        As :func:`bag_topics`; also for an embedded definition that does not parse.

    """
    store = base if base is not None else default_typestore()
    with _open_reader(path) as reader:
        missing = {c.msgtype: c.msgdef for c in reader.connections
                   if c.msgtype not in store.fielddefs}
    if not missing:
        return store
    own = Typestore()
    own.register(store.fielddefs)
    for msgtype, definition in missing.items():
        if not definition.data:
            msg = (f'bag {path} holds no definition of {msgtype}, which this machine does not '
                   'know either (is the workspace sourced?)')
            raise MalformedBagError(msg)
        try:
            types = (get_types_from_idl(definition.data)
                     if definition.format == MessageDefinitionFormat.IDL
                     else get_types_from_msg(definition.data, msgtype))
        except (TypesysError, ValueError) as exc:
            msg = f'bag {path}: the definition of {msgtype} it holds does not parse: {exc}'
            raise MalformedBagError(msg) from exc
        own.register({name: fields for name, fields in types.items()
                      if name not in own.fielddefs})
    return own


def _qos_of(connection: Connection) -> list[Qos]:
    ext = connection.ext
    return list(ext.offered_qos_profiles) if isinstance(ext, ConnectionExtRosbag2) else []


@contextmanager
def read_messages(path: str | Path,
                  topics: Collection[str] | None = None) -> Iterator[Iterator[BagMessage]]:
    """Open a bag and give its messages in time order, as :class:`BagMessage` tuples.

    Use as ``with read_messages(bag) as messages: for topic, msgtype, t_ns, data in
    messages: ...``; the bag is closed on leaving the block.

    Parameters
    ----------
    path : str or Path
        Bag directory (or a complete ``.mcap`` file).
    topics : Collection[str] or None
        Only these topics (default: all).

    Raises
    ------
    BagNotFoundError, UnfinishedBagError, MalformedBagError
        As :func:`bag_topics`, also for a chunk found corrupt while reading.
    BagError
        If a requested topic is not in the bag (naming the topics it has).

    """
    with _open_reader(path) as reader:
        connections = reader.connections
        if topics is not None:
            unknown = sorted(set(topics) - {c.topic for c in connections})
            if unknown:
                known = ', '.join(sorted({c.topic for c in connections})) or 'none'
                msg = f'bag {path} has no topic {", ".join(unknown)}; its topics: {known}'
                raise BagError(msg)
            connections = [c for c in connections if c.topic in topics]

        def messages() -> Iterator[BagMessage]:
            if not connections:
                return
            try:
                for connection, timestamp, data in reader.messages(connections):
                    yield BagMessage(connection.topic, connection.msgtype, timestamp,
                                     bytes(data))
            except (ReaderError, KeyError, ValueError, struct.error) as exc:
                msg = f'bag {path} is corrupt: {exc}'
                raise MalformedBagError(msg) from exc

        yield messages()


@dataclass(frozen=True)
class TopicSummary:
    """What a bag holds on one topic."""

    topic: str
    msgtype: str
    count: int
    #: Time of the first and last message [ns since the epoch]; 0 without messages.
    first_ns: int
    last_ns: int
    offered_qos: tuple[Qos, ...]

    @property
    def rate_hz(self) -> float | None:
        """Mean message rate [Hz] between the first and last message; None below two."""
        span_ns = self.last_ns - self.first_ns
        return (self.count - 1) * 1e9 / span_ns if self.count > 1 and span_ns > 0 else None


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds."""

    path: Path
    topics: list[TopicSummary]
    gaps: list[Gap] = field(default_factory=list)

    @property
    def message_count(self) -> int:
        """Messages on every topic."""
        return sum(topic.count for topic in self.topics)

    @property
    def start_ns(self) -> int:
        """Time of the first message [ns since the epoch]; 0 for an empty bag."""
        return min((t.first_ns for t in self.topics if t.count), default=0)

    @property
    def end_ns(self) -> int:
        """Time of the last message [ns since the epoch]; 0 for an empty bag."""
        return max((t.last_ns for t in self.topics if t.count), default=0)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last message [s]."""
        return (self.end_ns - self.start_ns) * 1e-9


def bag_summary(path: str | Path) -> BagSummary:
    """Summarise a bag: its topics, their types, counts, time spans and rates.

    Reads every message's time (not its data), so it takes a while on a long bag.

    Raises
    ------
    BagNotFoundError, UnfinishedBagError, MalformedBagError
        As :func:`read_messages`.

    """
    topics = bag_topics(path)
    spans: dict[str, list[int]] = {}
    gaps = GapFinder()
    with read_messages(path) as messages:
        for message in messages:
            gaps.take(message.topic, message.timestamp_ns)
            span = spans.setdefault(message.topic, [message.timestamp_ns, message.timestamp_ns,
                                                    0])
            span[0] = min(span[0], message.timestamp_ns)
            span[1] = max(span[1], message.timestamp_ns)
            span[2] += 1
    summaries = []
    for topic in topics:
        first, last, count = spans.get(topic.topic, [0, 0, 0])
        summaries.append(TopicSummary(topic.topic, topic.msgtype, count, first, last,
                                      topic.offered_qos))
    return BagSummary(Path(path).expanduser(), summaries, gaps.gaps)


def format_summary(summary: BagSummary) -> str:
    """Return a bag summary as the lines ``exo-has bag info`` prints."""
    lines = [f'bag:       {summary.path}']
    if summary.message_count:
        start = datetime.fromtimestamp(summary.start_ns * 1e-9, tz=timezone.utc)
        lines.append(f'start:     {start:%Y-%m-%d %H:%M:%S.%f} UTC ({summary.start_ns} ns)')
    lines += [f'duration:  {summary.duration_s:.3f} s',
              f'messages:  {summary.message_count}',
              f'topics:    {len(summary.topics)}']
    width = max([len('topic'), *(len(t.topic) for t in summary.topics)])
    type_width = max([len('type'), *(len(t.msgtype) for t in summary.topics)])
    lines.append(f'  {"topic":<{width}}  {"type":<{type_width}}  {"count":>8}  {"rate [Hz]":>9}  '
                 'qos')
    for topic in summary.topics:
        rate = f'{topic.rate_hz:9.2f}' if topic.rate_hz is not None else f'{"-":>9}'
        lines.append(f'  {topic.topic:<{width}}  {topic.msgtype:<{type_width}}  '
                     f'{topic.count:>8}  {rate}  {_describe_qos(topic.offered_qos)}')
    lines.append(f'gaps:      {len(summary.gaps) or "none"}')
    lines += [f'  {gap.describe()}' for gap in summary.gaps]
    return '\n'.join(lines)


def _describe_qos(profiles: Sequence[Qos]) -> str:
    kinds = sorted({f'{q.reliability.name.lower()}/{q.durability.name.lower()}'
                    for q in profiles})
    return ', '.join(kinds) if kinds else 'not recorded'

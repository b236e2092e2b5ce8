"""Bags: rosbag2 directories (MCAP storage, metadata version 9) of CDR messages.

Writing goes through rosbags' rosbag2 ``Writer``. Every topic's MCAP schema holds its full
message definition (encoding ``ros2msg``, the ``.msg`` text with comments for the types whose
file is found, then one ``MSG:`` section per nested type, as rosbag2 embeds it), so Jazzy's
``ros2 bag info/play``, Foxglove and Lichtblick read the bag without our packages. Types come
from the standalone backend's message registry (the Jazzy standard set plus this workspace's
interface packages); a type neither knows is looked up as ``share/<pkg>/msg/<Name>.msg`` under
``AMENT_PREFIX_PATH``.

How rosbags' MCAP writer lays a bag out, and what a crash loses: the file starts with the magic
and a Header record; schemas, channels and messages are appended to an in-memory chunk, which
becomes one uncompressed (or, on request, zstd) Chunk record on disk, followed by its
MessageIndex records, once it exceeds 1 MiB; the summary, the footer and ``metadata.yaml`` are
only written by ``close()``. A process killed before ``close()`` (SIGKILL, power loss) leaves an
``.mcap`` file without summary and footer and no ``metadata.yaml``, which no reader opens.
:class:`BagWriter` therefore also closes the chunk and syncs the file on :meth:`BagWriter.flush`
(the recorder calls it every second), and :func:`recover_bag` reads such a file record by
record with a reader of its own and rewrites a complete bag from every record that was wholly
written.
"""

from __future__ import annotations

import argparse
import mmap
import os
import re
import shutil
import struct
import sys
import threading
import zlib
from collections.abc import Collection, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import cache
from pathlib import Path
from queue import SimpleQueue
from types import TracebackType
from typing import Any, NamedTuple, Protocol, cast

from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    Nodetype,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    Reader,
    ReaderError,
    StoragePlugin,
    Writer,
    WriterError,
)
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from exo_has_runtime.errors import (
    BagError,
    BagNotFoundError,
    MalformedBagError,
    UnfinishedBagError,
    UnknownMessageTypeError,
)
from exo_has_runtime.recording import OfferedProfile

#: The bytes an MCAP file starts and ends with.
MCAP_MAGIC = b'\x89MCAP0\r\n'

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_DATA_END = 0x0F
_RECORD_NAMES = {
    1: 'Header', 2: 'Footer', 3: 'Schema', 4: 'Channel', 5: 'Message', 6: 'Chunk',
    7: 'MessageIndex', 8: 'ChunkIndex', 9: 'Attachment', 10: 'AttachmentIndex',
    11: 'Statistics', 12: 'Metadata', 13: 'MetadataIndex', 14: 'SummaryOffset', 15: 'DataEnd',
}
_RECORD_HEAD = 9  # opcode (1 byte) and content length (8 bytes)
_SEPARATOR = '=' * 80 + '\n'
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
_MESSAGE_HEAD = struct.Struct('<HIQQ')  # channel id, sequence, log time, publish time
_CHUNK_HEAD = struct.Struct('<QQQI')  # start time, end time, uncompressed size, crc32


# --- message definitions -----------------------------------------------------------------------


@cache
def default_typestore() -> Typestore:
    """Return the typestore bags are written with: the standalone backend's registry's.

    It holds the Jazzy standard set and this workspace's interface packages (and whatever
    :func:`ensure_message_type` adds). Without the DDS binding (a robot PC running rclpy), the
    Jazzy set alone, to which the ament index adds the rest on demand.
    """
    try:
        from exo_has_runtime.standalone.messages import default_registry
    except ImportError:
        return get_typestore(Stores.ROS2_JAZZY)
    return default_registry().typestore


@cache
def _workspace_msg_files() -> dict[str, Path]:
    try:
        from exo_has_runtime.standalone.messages import find_msg_files, interface_search_paths
    except ImportError:
        return {}
    return find_msg_files(interface_search_paths())


def msg_file(msgtype: str) -> Path | None:
    """Return the ``.msg`` file defining a type, if one is found.

    The workspace's interface packages (as the message registry finds them) come first, then
    ``<prefix>/share/<pkg>/msg/<Name>.msg`` for each prefix of ``AMENT_PREFIX_PATH``.
    """
    name = _normalize(msgtype)
    found = _workspace_msg_files().get(name)
    if found is not None:
        return found
    package, _, short = name.split('/')
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        candidate = Path(prefix, 'share', package, 'msg', f'{short}.msg')
        if prefix and candidate.is_file():
            return candidate
    return None


def _normalize(msgtype: str) -> str:
    parts = msgtype.split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and all(parts):
        return msgtype
    msg = f'malformed message type name {msgtype!r}: expected "package/msg/Name"'
    raise UnknownMessageTypeError(msg)


def ensure_message_type(msgtype: str, typestore: Typestore) -> None:
    """Make sure the typestore knows a type and every type it nests, from ``.msg`` files.

    Raises
    ------
    UnknownMessageTypeError
        Naming the first type that neither the typestore nor a ``.msg`` file defines.

    """
    pending = [_normalize(msgtype)]
    while pending:
        name = pending.pop()
        if name in typestore.fielddefs:
            continue
        source = msg_file(name)
        if source is None:
            msg = (
                f'message type {name!r} is unknown: neither the Jazzy standard set, this '
                'workspace nor AMENT_PREFIX_PATH defines it'
            )
            raise UnknownMessageTypeError(msg)
        try:
            typestore.register(get_types_from_msg(source.read_text(encoding='utf-8'), name))
        except TypesysError as exc:
            msg = f'{source}: cannot parse message definition: {exc}'
            raise UnknownMessageTypeError(msg) from exc
        for _, node in typestore.fielddefs[name][1]:
            nested = _nested_type(node)
            if nested is not None:
                pending.append(nested)


def _nested_type(node: object) -> str | None:
    """Return the message type a field definition refers to, through arrays and sequences."""
    kind, argument = cast('tuple[Nodetype, Any]', node)
    while kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        kind, argument = cast('tuple[Nodetype, Any]', argument[0])
    return str(argument) if kind == Nodetype.NAME else None


def message_definition(msgtype: str, typestore: Typestore | None = None) -> tuple[str, str]:
    """Return a type's full definition, as rosbag2 embeds it in a bag, and its type hash.

    Parameters
    ----------
    msgtype : str
        ``pkg/msg/Name``.
    typestore : Typestore or None
        Where the types are defined (default: :func:`default_typestore`).

    Returns
    -------
    tuple[str, str]
        The definition (``ros2msg``): the type's own text, then for each nested type a line of
        80 ``=``, ``MSG: pkg/Name`` and its text; each text is the ``.msg`` file's, comments
        included, where the file is found, else the typestore's. Then the REP 2011 hash
        (``RIHS01_<hex>``).

    Raises
    ------
    UnknownMessageTypeError
        If the type, or one it nests, is not defined anywhere.

    """
    store = typestore if typestore is not None else default_typestore()
    name = _normalize(msgtype)
    ensure_message_type(name, store)
    generated, _ = store.generate_msgdef(name, ros_version=2)
    sections = []
    for index, section in enumerate(generated.split(_SEPARATOR)):
        header, body = ('', section) if index == 0 else section.split('\n', 1)
        source = msg_file(name if index == 0 else header.removeprefix('MSG: '))
        if source is not None:
            body = source.read_text(encoding='utf-8').rstrip('\n') + '\n'
        sections.append(body if index == 0 else f'{header}\n{body}')
    return _SEPARATOR.join(sections), store.hash_rihs01(name)


# --- QoS ---------------------------------------------------------------------------------------


class _DurationLike(Protocol):
    @property
    def nanoseconds(self) -> int: ...


class QosProfileLike(OfferedProfile, Protocol):
    """What :func:`offered_qos` reads of an rclpy (or standalone) ``QoSProfile``."""

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


def offered_qos(profile: QosProfileLike) -> Qos:
    """Return a ROS 2 QoS profile as the rosbags ``Qos`` a bag's metadata records.

    The policies are numbered alike in rmw, rclpy and rosbags.
    """
    def time_of(duration: _DurationLike) -> QosTime:
        seconds, nanoseconds = divmod(int(duration.nanoseconds), 1_000_000_000)
        return QosTime(seconds, nanoseconds)

    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               time_of(profile.deadline), time_of(profile.lifespan),
               QosLiveliness(int(profile.liveliness)),
               time_of(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


# --- writing -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _AddTopic:
    topic: str
    msgtype: str
    definition: str
    type_hash: str
    qos: tuple[Qos, ...]


@dataclass(frozen=True)
class _Flush:
    done: threading.Event | None


@dataclass(frozen=True)
class _Close:
    pass


_Command = tuple[str, int, bytes] | _AddTopic | _Flush | _Close


class BagWriter:
    """Write a rosbag2 bag (MCAP storage, version 9) of CDR messages, on a thread of its own.

    Callers only queue work, so a node's callbacks never wait for the disk (the CPU work of
    writing shares the GIL still), and a KeyboardInterrupt, raised in the main thread, can never
    tear a record apart.

    Parameters
    ----------
    path : str or Path
        Bag directory to create; it must not exist.
    typestore : Typestore or None
        Where message types are defined (default: :func:`default_typestore`).
    compress : bool
        Compress each chunk with zstd (smaller files, more CPU).

    Raises
    ------
    BagError
        If the directory exists or cannot be created.

    """

    def __init__(self, path: str | Path, *, typestore: Typestore | None = None,
                 compress: bool = False) -> None:
        self.path = Path(path).expanduser().absolute()
        self._typestore = typestore if typestore is not None else default_typestore()
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
            if compress:
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer.open()
        except (WriterError, OSError) as exc:
            msg = f'cannot create bag {self.path}: {exc}'
            raise BagError(msg) from exc
        if not isinstance(self._writer.storage, McapWriter) \
                or not callable(getattr(self._writer.storage, 'close_chunk', None)):
            # flush() closes rosbags' pending chunk: an internal the pinned versions share.
            self._writer.abort()
            msg = 'this rosbags version has no McapWriter.close_chunk(): install rosbags 0.11'
            raise BagError(msg)
        self._topics: dict[str, str] = {}
        self._counts: dict[str, int] = {}
        self._queue: SimpleQueue[_Command] = SimpleQueue()
        self._error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f'bag {self.path.name}',
                                        daemon=True)
        self._thread.start()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @property
    def topics(self) -> dict[str, str]:
        """Message type of each topic added, by topic."""
        return dict(self._topics)

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, by topic (final once closed)."""
        return {topic: self._counts.get(topic, 0) for topic in self._topics}

    def add_topic(self, topic: str, msgtype: str, offered_qos: Iterable[Qos] = ()) -> None:
        """Add a topic before writing its messages.

        Parameters
        ----------
        topic : str
            Fully qualified topic name.
        msgtype : str
            ``pkg/msg/Name``.
        offered_qos : Iterable[Qos]
            The QoS of each publisher seen on the topic, recorded for replay.

        Raises
        ------
        UnknownMessageTypeError
            If the type's definition is not found.
        BagError
            If the topic was added already, or the bag is closed or failed.

        """
        self._check_usable()
        if topic in self._topics:
            msg = f'topic {topic!r} is in bag {self.path} already'
            raise BagError(msg)
        definition, type_hash = message_definition(msgtype, self._typestore)
        self._topics[topic] = _normalize(msgtype)
        self._queue.put(_AddTopic(topic, _normalize(msgtype), definition, type_hash,
                                  tuple(offered_qos)))

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Queue one message: CDR bytes (with their encapsulation header) and a time [ns].

        Raises
        ------
        BagError
            If the topic was not added, or the bag is closed or failed.

        """
        if topic not in self._topics:
            msg = f'topic {topic!r} was not added to bag {self.path}'
            raise BagError(msg)
        if self._error is not None or self._closed:
            self._check_usable()
        self._queue.put((topic, timestamp_ns, bytes(data)))

    def flush(self, wait: bool = False) -> None:
        """Put every message queued so far on disk, as a complete chunk, and sync the file.

        A process killed afterwards loses none of these messages (:func:`recover_bag`).

        Parameters
        ----------
        wait : bool
            Return only once it is done.

        """
        self._check_usable()
        done = threading.Event() if wait else None
        self._queue.put(_Flush(done))
        if done is not None:
            while not done.wait(0.1) and self._thread.is_alive():
                pass
            self._check_usable()

    def close(self) -> dict[str, int]:
        """Write the remaining messages, the MCAP summary and metadata.yaml; wait for it.

        Returns
        -------
        dict[str, int]
            Messages written, by topic.

        Raises
        ------
        BagError
            If writing failed (what was written before the failure is closed properly).

        """
        if not self._closed:
            self._closed = True
            self._queue.put(_Close())
            while self._thread.is_alive():
                try:
                    self._thread.join()
                except KeyboardInterrupt:  # a second Ctrl-C must not leave the bag half-closed
                    continue
            if self._error is not None:
                msg = f'writing bag {self.path} failed: {self._error}'
                raise BagError(msg) from self._error
        return self.counts

    def _check_usable(self) -> None:
        if self._error is not None:
            msg = f'writing bag {self.path} failed: {self._error}'
            raise BagError(msg) from self._error
        if self._closed:
            msg = f'bag {self.path} is closed'
            raise BagError(msg)

    def _run(self) -> None:
        writer = self._writer
        connections: dict[str, Connection] = {}
        while True:
            item = self._queue.get()
            try:
                if isinstance(item, tuple):
                    if self._error is None:
                        writer.write(connections[item[0]], item[1], item[2])
                        self._counts[item[0]] = self._counts.get(item[0], 0) + 1
                elif isinstance(item, _AddTopic):
                    if self._error is None:
                        connections[item.topic] = writer.add_connection(
                            item.topic, item.msgtype, msgdef=item.definition,
                            rihs01=item.type_hash, serialization_format='cdr',
                            offered_qos_profiles=item.qos)
                elif isinstance(item, _Flush):
                    if self._error is None:
                        self._flush_storage()
                    if item.done is not None:
                        item.done.set()
                else:
                    writer.close()
                    return
            except Exception as exc:  # disk full, say: reported to the caller, not lost
                if self._error is None:
                    self._error = exc
                if isinstance(item, _Close):
                    return

    def _flush_storage(self) -> None:
        storage = self._writer.storage
        assert isinstance(storage, McapWriter)
        if storage.chunk.msgs:  # a chunk of schemas and channels only waits for messages
            storage.close_chunk()
        storage.bio.flush()
        os.fsync(storage.bio.fileno())


# --- reading -----------------------------------------------------------------------------------


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
                    yield BagMessage(connection.topic, connection.msgtype, timestamp, data)
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
    with read_messages(path) as messages:
        for message in messages:
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
    return BagSummary(Path(path).expanduser(), summaries)


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
    return '\n'.join(lines)


def _describe_qos(profiles: Sequence[Qos]) -> str:
    kinds = sorted({f'{q.reliability.name.lower()}/{q.durability.name.lower()}'
                    for q in profiles})
    return ', '.join(kinds) if kinds else 'not recorded'


# --- reading an MCAP file record by record -----------------------------------------------------


class McapSchema(NamedTuple):
    """An MCAP Schema record."""

    id: int
    name: str
    encoding: str
    data: bytes


class McapChannel(NamedTuple):
    """An MCAP Channel record."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


class McapMessage(NamedTuple):
    """An MCAP Message record; times in ns."""

    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


class _ShortRecordError(Exception):
    """A field that reaches past the end of its record."""


class _Fields:
    """Little-endian fields read one after the other from a record's content."""

    def __init__(self, data: bytes, offset: int = 0, end: int | None = None) -> None:
        self.data = data
        self.offset = offset
        self.end = len(data) if end is None else end

    def take(self, size: int) -> bytes:
        if size < 0 or self.offset + size > self.end:
            raise _ShortRecordError
        start, self.offset = self.offset, self.offset + size
        return self.data[start:self.offset]

    def unpack(self, layout: struct.Struct) -> tuple[int, ...]:
        return tuple(layout.unpack(self.take(layout.size)))

    def integer(self, layout: struct.Struct) -> int:
        return int(layout.unpack(self.take(layout.size))[0])

    def string(self) -> str:
        return self.take(self.integer(_U32)).decode('utf-8')


def _schema(content: bytes) -> McapSchema:
    fields = _Fields(content)
    return McapSchema(fields.integer(_U16), fields.string(), fields.string(),
                      fields.take(fields.integer(_U32)))


def _channel(content: bytes) -> McapChannel:
    fields = _Fields(content)
    ident, schema_id = fields.integer(_U16), fields.integer(_U16)
    topic, encoding = fields.string(), fields.string()
    entries = _Fields(fields.take(fields.integer(_U32)))
    metadata = {}
    while entries.offset < entries.end:
        key = entries.string()
        metadata[key] = entries.string()
    return McapChannel(ident, schema_id, topic, encoding, metadata)


def _message(content: bytes) -> McapMessage:
    if len(content) < _MESSAGE_HEAD.size:
        raise _ShortRecordError
    channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(content)
    return McapMessage(channel_id, sequence, log_time, publish_time,
                       content[_MESSAGE_HEAD.size:])


def _decompress(data: bytes, compression: str) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        if sys.version_info >= (3, 14):
            from compression import zstd  # pragma: no cover
        else:
            from backports import zstd
        return zstd.decompress(data)
    if compression == 'lz4':
        import lz4.frame  # type: ignore[import-untyped, unused-ignore]
        return bytes(lz4.frame.decompress(data))
    msg = f'unknown chunk compression {compression!r}'
    raise ValueError(msg)


class McapScanner:
    """Read an MCAP file front to back, record by record, as far as it was written.

    Needs neither summary nor footer, so it reads the file of a writer that was killed: it
    stops at the first record the file ends inside of (torn), or whose opcode is 0 (never
    written), and says so in :attr:`stop_reason`. From an uncompressed chunk that is torn it
    still takes the records written whole. A chunk whose decompression or CRC fails is skipped
    (noted in :attr:`bad_chunks`), the records after it are read.

    Parameters
    ----------
    path : Path
        The ``.mcap`` file.

    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = 0
        self.schemas: dict[int, McapSchema] = {}
        self.channels: dict[int, McapChannel] = {}
        #: The data section ended (DataEnd or Footer record read): nothing is missing.
        self.complete = False
        #: Offset after the last record read whole [bytes].
        self.good_until = 0
        #: Chunks read whole.
        self.chunks = 0
        #: Messages taken from the complete records of a torn chunk.
        self.salvaged = 0
        self.bad_chunks: list[str] = []
        self.stop_reason = ''

    def records(self) -> Iterator[McapChannel | McapMessage]:
        """Give each channel (when first defined) and each message, in file order.

        Raises
        ------
        BagNotFoundError
            If the file does not exist.
        MalformedBagError
            If the file is empty or not an MCAP file.

        """
        try:
            file = self.path.open('rb')
        except FileNotFoundError as exc:
            msg = f'no MCAP file at {self.path}'
            raise BagNotFoundError(msg) from exc
        with file:
            self.size = os.fstat(file.fileno()).st_size
            if self.size == 0:
                msg = f'{self.path} is empty: its writer never wrote to it'
                raise MalformedBagError(msg)
            with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
                yield from self._scan(data)

    def _scan(self, data: mmap.mmap) -> Iterator[McapChannel | McapMessage]:
        head = bytes(data[:len(MCAP_MAGIC)])
        if head != MCAP_MAGIC:
            if len(head) < len(MCAP_MAGIC) and MCAP_MAGIC.startswith(head):
                self.stop_reason = f'the file ends inside the magic, after {self.size} bytes'
                return
            msg = f'{self.path} is not an MCAP file: it starts with {head!r}'
            raise MalformedBagError(msg)
        position = self.good_until = len(MCAP_MAGIC)
        while True:
            if position == self.size:
                self.stop_reason = (f'the file ends after the record ending at byte {position} '
                                    '(the writer never wrote the summary and footer)')
                return
            if self.size - position < _RECORD_HEAD:
                self.stop_reason = f'a record starting at byte {position} is torn'
                return
            opcode = data[position]
            length = int(_U64.unpack_from(data, position + 1)[0])
            name = _RECORD_NAMES.get(opcode, f'opcode 0x{opcode:02x}')
            end = position + _RECORD_HEAD + length
            if opcode == 0:
                self.stop_reason = f'bytes from {position} on are not records (opcode 0)'
                return
            if end > self.size:
                self.stop_reason = (f'the {name} record at byte {position} is torn: it needs '
                                    f'{end - position} bytes, the file has {self.size - position}')
                if opcode == _OP_CHUNK:
                    yield from self._salvage(data[position + _RECORD_HEAD:self.size], position)
                return
            content = data[position + _RECORD_HEAD:end]
            try:
                if opcode == _OP_CHUNK:
                    yield from self._chunk(content, position)
                elif opcode in (_OP_DATA_END, _OP_FOOTER):
                    self.complete = True
                    self.good_until = self.size
                    self.stop_reason = 'the data section is complete'
                    return
                else:
                    yield from self._plain_records([(opcode, content)])
            except (_ShortRecordError, UnicodeDecodeError) as exc:
                self.stop_reason = f'the {name} record at byte {position} is malformed ({exc!r})'
                return
            position = self.good_until = end

    def _plain_records(self, records: Iterable[tuple[int, bytes]]
                       ) -> Iterator[McapChannel | McapMessage]:
        for opcode, content in records:
            if opcode == _OP_SCHEMA:
                schema = _schema(content)
                self.schemas.setdefault(schema.id, schema)
            elif opcode == _OP_CHANNEL:
                channel = _channel(content)
                if channel.id not in self.channels:
                    self.channels[channel.id] = channel
                    yield channel
            elif opcode == _OP_MESSAGE:
                yield _message(content)

    def _inner_records(self, data: bytes) -> tuple[list[tuple[int, bytes]], int]:
        """Split a chunk's records; give the offset after the last one written whole."""
        records = []
        fields = _Fields(data)
        whole = 0
        while fields.offset < fields.end:
            try:
                opcode = fields.take(1)[0]
                records.append((opcode, fields.take(fields.integer(_U64))))
            except _ShortRecordError:
                break
            whole = fields.offset
        return records, whole

    def _chunk(self, content: bytes, position: int) -> Iterator[McapChannel | McapMessage]:
        fields = _Fields(content)
        _, _, size, crc = fields.unpack(_CHUNK_HEAD)
        compression = fields.string()
        compressed = fields.take(fields.integer(_U64))
        try:
            data = _decompress(compressed, compression)
        except Exception as exc:  # each decompressor raises errors of its own
            self.bad_chunks.append(f'the chunk at byte {position} does not decompress ({exc})')
            return
        if len(data) != size or (crc and zlib.crc32(data) != crc):
            self.bad_chunks.append(f'the chunk at byte {position} fails its size or CRC check')
            return
        records, whole = self._inner_records(data)
        parsed, malformed = self._parse(records)
        if whole < len(data) or malformed:
            self.bad_chunks.append(f'the chunk at byte {position} ends in a torn or malformed '
                                   'record: the records before it are kept')
        self.chunks += 1
        yield from parsed

    def _parse(self, records: Iterable[tuple[int, bytes]]
               ) -> tuple[list[McapChannel | McapMessage], bool]:
        """Parse records up to the first malformed one; say whether there was one."""
        parsed: list[McapChannel | McapMessage] = []
        try:
            for record in self._plain_records(records):
                parsed.append(record)
        except (_ShortRecordError, UnicodeDecodeError):
            return parsed, True
        return parsed, False

    def _salvage(self, partial: bytes, position: int) -> Iterator[McapChannel | McapMessage]:
        fields = _Fields(partial)
        try:
            fields.unpack(_CHUNK_HEAD)
            compression = fields.string()
            fields.integer(_U64)
        except (_ShortRecordError, UnicodeDecodeError):
            return
        if compression:
            self.stop_reason += f' ({compression} chunk: its records cannot be salvaged)'
            return
        records, whole = self._inner_records(partial[fields.offset:])
        salvaged, _ = self._parse(records)
        if salvaged:
            self.good_until = position + _RECORD_HEAD + fields.offset + whole
        self.salvaged += sum(isinstance(record, McapMessage) for record in salvaged)
        yield from salvaged


# --- recovery ----------------------------------------------------------------------------------


@dataclass
class RecoveryReport:
    """What :func:`recover_bag` recovered of a bag, and what was lost."""

    source: Path
    #: The recovered bag (the source itself when recovered in place).
    output: Path
    #: The source bag was complete (closed properly); nothing was rewritten in place.
    already_complete: bool = False
    #: Messages recovered, by topic.
    messages: dict[str, int] = field(default_factory=dict)
    #: Time of the first and last message recovered [ns since the epoch].
    start_ns: int = 0
    end_ns: int = 0
    chunks: int = 0
    #: Messages taken from the part of a torn chunk that was written whole.
    salvaged: int = 0
    #: Bytes of the MCAP files, and of those that could not be read.
    file_bytes: int = 0
    lost_bytes: int = 0
    #: Where reading stopped, and chunks and channels that had to be left out.
    stop_reasons: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    #: Where the original files were kept (in-place recovery).
    kept_originals: list[Path] = field(default_factory=list)

    @property
    def message_count(self) -> int:
        """Messages recovered."""
        return sum(self.messages.values())

    def describe(self) -> str:
        """Say, in a few lines, what was recovered and what was lost."""
        if self.already_complete:
            return (f'{self.source} is complete (closed properly, {self.message_count} '
                    'messages): nothing to recover')
        span = (self.end_ns - self.start_ns) * 1e-9
        lines = [f'recovered {self.message_count} messages on {len(self.messages)} topics, '
                 f'{span:.3f} s, from {self.chunks} complete chunks'
                 + (f' and {self.salvaged} whole messages of a torn chunk' if self.salvaged
                    else '') + f', into {self.output}']
        lines += [f'  {topic}: {count}' for topic, count in sorted(self.messages.items())]
        if self.lost_bytes:
            lines.append(f'lost: the last {self.lost_bytes} of {self.file_bytes} bytes, and '
                         'the messages in them (never written whole); reading stopped as')
        else:
            lines.append('lost: no message (only the summary, footer and metadata.yaml were '
                         'missing)' if not self.problems else 'lost: no byte; but')
        lines += [f'  {reason}' for reason in self.stop_reasons]
        lines += [f'  {problem}' for problem in self.problems]
        if self.kept_originals:
            kept = ', '.join(str(path) for path in self.kept_originals)
            lines.append(f'the original files are kept as {kept}')
        return '\n'.join(lines)


def _natural_key(path: Path) -> list[object]:
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', path.name)]


def _mcap_files(source: Path) -> list[Path]:
    if not source.exists():
        msg = f'no bag at {source}'
        raise BagNotFoundError(msg)
    if source.is_file():
        return [source]
    files = sorted(source.glob('*.mcap'), key=_natural_key)
    if not files:
        msg = f'{source} holds no .mcap file: there is nothing to recover'
        raise MalformedBagError(msg)
    return files


def _is_complete(source: Path, files: Sequence[Path]) -> bool:
    if not source.is_dir() or not (source / 'metadata.yaml').is_file():
        return False
    for file in files:
        with file.open('rb') as stream:
            size = stream.seek(0, os.SEEK_END)
            if size < 2 * len(MCAP_MAGIC):
                return False
            stream.seek(size - len(MCAP_MAGIC))
            if stream.read() != MCAP_MAGIC:
                return False
    return True


def _schema_hash(schema: McapSchema, definition: str) -> str:
    typestore = get_typestore(Stores.EMPTY)
    try:
        typestore.register(get_types_from_msg(definition, schema.name))
        return typestore.hash_rihs01(schema.name)
    except (TypesysError, KeyError, ValueError):
        # A definition that is not ros2msg: trust our own typestore for the name, if it knows it.
        fallback = default_typestore()
        ensure_message_type(schema.name, fallback)
        return fallback.hash_rihs01(schema.name)


def recover_bag(path: str | Path, output: str | Path | None = None) -> RecoveryReport:
    """Rewrite a bag whose writer was killed as a complete one, with all it can read.

    The ``.mcap`` files are read record by record (:class:`McapScanner`): every message whose
    record was written whole is kept, in file order, on the topics, types, definitions and QoS
    the file records; reading stops at the first torn record. The result is a complete rosbag2
    directory (one ``.mcap`` with summary and footer, and ``metadata.yaml``).

    Parameters
    ----------
    path : str or Path
        The bag directory (or one ``.mcap`` file).
    output : str or Path or None
        New bag directory for the result. Default: the bag directory itself, in place; its
        original files are kept beside, renamed ``*.orig``. A bag that is complete already is
        then left alone. For a lone ``.mcap`` file the default is ``<stem>_recovered`` beside it.

    Returns
    -------
    RecoveryReport
        What was recovered and lost (:meth:`RecoveryReport.describe`).

    Raises
    ------
    BagNotFoundError
        If there is no bag at the path.
    MalformedBagError
        If it holds no MCAP file, or a file is not MCAP.
    BagError
        If the output exists, or an original's ``.orig`` name is taken.

    """
    source = Path(path).expanduser().absolute()
    files = _mcap_files(source)
    in_place = output is None and source.is_dir()
    if in_place and _is_complete(source, files):
        return RecoveryReport(source, source, already_complete=True, messages={
            topic.topic: topic.count for topic in bag_topics(source)})
    if in_place:
        staging_root = source / '.recovering'
        shutil.rmtree(staging_root, ignore_errors=True)  # left by an interrupted recovery
        target = staging_root / source.name
        originals = [file.with_name(file.name + '.orig')
                     for file in [*files, source / 'metadata.yaml'] if file.exists()]
        taken = [str(kept) for kept in originals if kept.exists()]
        if taken:
            msg = f'cannot keep the original files: {", ".join(taken)} exist already'
            raise BagError(msg)
    else:
        target = Path(output).expanduser().absolute() if output is not None \
            else source.with_name(f'{source.stem}_recovered')
        if target.exists():
            msg = f'{target} exists already: give another output directory'
            raise BagError(msg)
    report = RecoveryReport(source, source if in_place else target)
    try:
        _rewrite(files, target, report)
    except BaseException:
        shutil.rmtree(staging_root if in_place else target, ignore_errors=True)
        raise
    if in_place:
        for original in [*files, source / 'metadata.yaml']:
            if original.exists():
                kept = original.with_name(original.name + '.orig')
                original.rename(kept)
                report.kept_originals.append(kept)
        for produced in sorted(target.iterdir(), key=lambda p: p.name == 'metadata.yaml'):
            produced.rename(source / produced.name)  # metadata.yaml last: it makes the bag
        shutil.rmtree(staging_root)
    return report


def _rewrite(files: Sequence[Path], target: Path, report: RecoveryReport) -> None:
    with Writer(target, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data('exo_has.recovered_from', ', '.join(str(f) for f in files))
        by_key: dict[tuple[str, str, str, str], Connection] = {}
        for file in files:
            scanner = McapScanner(file)
            connections: dict[int, Connection] = {}
            for record in scanner.records():
                if isinstance(record, McapChannel):
                    connection = _connection_for(writer, record, scanner, by_key, report)
                    if connection is not None:
                        connections[record.id] = connection
                        report.messages.setdefault(connection.topic, 0)
                    continue
                connection = connections.get(record.channel_id)
                if connection is None:
                    continue
                writer.write(connection, record.log_time, record.data)
                report.messages[connection.topic] = report.messages.get(connection.topic, 0) + 1
                report.start_ns = record.log_time if not report.start_ns \
                    else min(report.start_ns, record.log_time)
                report.end_ns = max(report.end_ns, record.log_time)
            report.chunks += scanner.chunks
            report.salvaged += scanner.salvaged
            report.file_bytes += scanner.size
            report.lost_bytes += scanner.size - scanner.good_until
            if not scanner.complete:
                report.stop_reasons.append(f'{file.name}: {scanner.stop_reason}')
            report.problems += [f'{file.name}: {bad}' for bad in scanner.bad_chunks]
        writer.set_custom_data('exo_has.lost_bytes', str(report.lost_bytes))


def _connection_for(writer: Writer, channel: McapChannel, scanner: McapScanner,
                    by_key: dict[tuple[str, str, str, str], Connection],
                    report: RecoveryReport) -> Connection | None:
    schema = scanner.schemas.get(channel.schema_id)
    if schema is None:
        report.problems.append(f'channel {channel.topic!r} has no schema: its messages are '
                               'left out (a rosbag2 topic needs a type)')
        return None
    qos_text = channel.metadata.get('offered_qos_profiles', '')
    key = (channel.topic, schema.name, channel.message_encoding, qos_text)
    known = by_key.get(key)
    if known is not None:
        return known
    definition = schema.data.decode('utf-8')
    try:
        type_hash = _schema_hash(schema, definition)
        qos = parse_qos(qos_text) if qos_text else []
        connection = writer.add_connection(
            channel.topic, schema.name, msgdef=definition, rihs01=type_hash,
            serialization_format=channel.message_encoding, offered_qos_profiles=qos)
    except (UnknownMessageTypeError, ReaderError, WriterError) as exc:
        report.problems.append(f'channel {channel.topic!r} ({schema.name}) cannot be '
                               f'rewritten, its messages are left out: {exc}')
        return None
    by_key[key] = connection
    return connection


# --- exo-has bag -------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``exo-has bag info BAG`` or ``exo-has bag recover BAG [--output DIR]``."""
    parser = argparse.ArgumentParser(prog='exo-has bag', description='Inspect and recover bags.')
    actions = parser.add_subparsers(dest='action', required=True, metavar='ACTION')
    info = actions.add_parser('info', help='topics, types, counts, duration and rates of a bag')
    info.add_argument('bag', help='bag directory')
    recover = actions.add_parser(
        'recover', help='rewrite a bag whose recorder was killed, up to its last complete chunk')
    recover.add_argument('bag', help='bag directory (or .mcap file)')
    recover.add_argument('--output', '-o', default=None,
                         help='new bag directory (default: in place, originals kept as *.orig)')
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.action == 'info':
            print(format_summary(bag_summary(args.bag)))
        else:
            print(recover_bag(args.bag, args.output).describe())
    except BagError as exc:
        print(f'exo-has bag {args.action}: {exc}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())

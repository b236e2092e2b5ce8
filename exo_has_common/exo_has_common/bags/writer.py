"""Writing bags: rosbag2 MCAP (metadata version 9) with the ``mcap`` package, flushed by chunks.

The bag is what ``ros2 bag record`` writes with its MCAP storage: a directory holding one
``.mcap`` file (profile ``ros2``; per type a Schema record, encoding ``ros2msg``, with the full
definition; per topic a Channel record, encoding ``cdr``, whose metadata gives the offered QoS
(``offered_qos_profiles``) and the type hash (``topic_type_hash``); per message a Message record
of CDR bytes, its log and publish times both the time the recorder stamped it with) and
``metadata.yaml``. ``mcap`` was preferred to rosbags' writer, which ``bench/bag_writer.py``
measures cheaper by 0.3 to 1.7 us of mcap's 5 to 6.5 us per message (at most 0.35 % of a core
at the whole system's 2000 messages a second), because it closes a chunk early through its
public ``flush()`` (rosbags only through internals of its storage plugin) and writes each
chunk's CRC, by which recovery tells a damaged chunk (rosbags writes none).

What a crash loses: ``mcap`` appends schemas, channels and messages to an in-memory chunk,
which goes to disk as one Chunk record (uncompressed, or zstd on request; with a CRC of its
content), followed by its MessageIndex records, once it exceeds :data:`CHUNK_SIZE`; the summary,
the footer and ``metadata.yaml`` are only written by :meth:`Rosbag2Writer.close`. A process
killed before that (SIGKILL, power loss) leaves an ``.mcap`` file without summary and footer and
no ``metadata.yaml``, which no reader opens. :meth:`Rosbag2Writer.flush` therefore writes the
pending chunk whole (``mcap``'s ``Writer.flush()``) and syncs the file (the recorder does it
every ``flush_period``), and :func:`exo_has_common.bags.recovery.recover_bag` reads such a file
record by record and rewrites a complete bag from every record written whole.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Qos
from rosbags.typesys.store import Typestore

from exo_has_common.bags.definitions import (
    default_typestore,
    message_definition,
    normalize_type_name,
)
from exo_has_common.bags.qos import qos_dicts, qos_yaml
from exo_has_common.errors import BagError

#: Size [bytes] at which a chunk is written out, if no flush came first (rosbag2's default).
CHUNK_SIZE = 1024 * 1024

#: What ``metadata.yaml`` names as its writer's ROS distribution when ``ROS_DISTRO`` is unset.
DEFAULT_ROS_DISTRO = 'jazzy'

#: Longest time [s] a queued message waits for the writing thread (but for a flush or close).
DRAIN_PERIOD_S = 0.02

_LIBRARY = f'exo_has_runtime bag writer, {LIBRARY_IDENTIFIER}'


@dataclass
class _Channel:
    topic: str
    msgtype: str
    serialization_format: str
    offered_qos: tuple[Qos, ...]
    type_hash: str
    count: int = 0


class Rosbag2Writer:
    """Write one rosbag2 bag (MCAP storage, version 9), in the calling thread.

    Parameters
    ----------
    path : str or Path
        Bag directory to create; it must not exist. The MCAP file is ``<name>.mcap`` in it.
    compress : bool
        Compress each chunk with zstd (smaller files, more CPU).

    Raises
    ------
    BagError
        If the directory exists or cannot be created.

    """

    def __init__(self, path: str | Path, *, compress: bool = False) -> None:
        self.path = Path(path).expanduser().absolute()
        self.file_path = self.path / f'{self.path.name}.mcap'
        #: Key-value pairs for ``metadata.yaml``'s ``custom_data``.
        self.custom_data: dict[str, str] = {}
        try:
            self.path.mkdir(parents=True)
        except FileExistsError:
            msg = f'cannot create bag {self.path}: it exists already'
            raise BagError(msg) from None
        except OSError as exc:
            msg = f'cannot create bag {self.path}: {exc}'
            raise BagError(msg) from exc
        self._stream: IO[bytes] = self.file_path.open('xb')
        self._mcap = McapWriter(self._stream, chunk_size=CHUNK_SIZE,
                                compression=CompressionType.ZSTD if compress
                                else CompressionType.NONE)
        self._mcap.start(profile='ros2', library=_LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, _Channel] = {}
        self._start_ns = 0
        self._end_ns = 0
        self._count = 0
        self._open = True

    @property
    def counts(self) -> dict[int, int]:
        """Messages written so far, by channel."""
        # list() copies at once: another thread may add a channel meanwhile.
        return {channel: info.count for channel, info in list(self._channels.items())}

    def add_channel(self, topic: str, msgtype: str, definition: str, type_hash: str,
                    offered_qos: Iterable[Qos] = (),
                    serialization_format: str = 'cdr') -> int:
        """Add a topic (its type's schema the first time the type comes); return its channel.

        Parameters
        ----------
        topic : str
            Fully qualified topic name.
        msgtype : str
            ``pkg/msg/Name``.
        definition : str
            The type's full ``ros2msg`` definition.
        type_hash : str
            Its ``RIHS01_`` hash.
        offered_qos : Iterable[Qos]
            The QoS of each publisher seen on the topic.
        serialization_format : str
            The messages' encoding.

        """
        schema = self._schemas.get(msgtype)
        if schema is None:
            schema = self._mcap.register_schema(msgtype, 'ros2msg', definition.encode())
            self._schemas[msgtype] = schema
        profiles = tuple(offered_qos)
        channel = self._mcap.register_channel(topic, serialization_format, schema, {
            'offered_qos_profiles': qos_yaml(profiles), 'topic_type_hash': type_hash})
        self._channels[channel] = _Channel(topic, msgtype, serialization_format, profiles,
                                           type_hash)
        return channel

    def write(self, channel: int, timestamp_ns: int, data: bytes) -> None:
        """Write one message: its serialized bytes and its time [ns since the epoch]."""
        self._mcap.add_message(channel, timestamp_ns, data, timestamp_ns)
        self._channels[channel].count += 1
        if self._count == 0 or timestamp_ns < self._start_ns:
            self._start_ns = timestamp_ns
        self._end_ns = max(self._end_ns, timestamp_ns)
        self._count += 1

    def flush(self) -> None:
        """Write the pending chunk whole and sync the file: a crash then loses none of it."""
        self._mcap.flush()  # type: ignore[no-untyped-call]  # mcap 1.6 leaves it unannotated
        os.fsync(self._stream.fileno())

    def close(self) -> None:
        """Write the summary and footer, close the file, then write ``metadata.yaml``.

        ``metadata.yaml`` is written last (and atomically): a bag that has it is complete.
        """
        if not self._open:
            return
        self._open = False
        try:
            information = self._information()
            self._mcap.add_metadata('rosbag2', {
                'serialized_metadata': yaml.safe_dump(information, sort_keys=False),
                'ROS_DISTRO': information['ros_distro']})
            self._mcap.finish()  # type: ignore[no-untyped-call]
        finally:
            self._stream.close()
        text = yaml.safe_dump({'rosbag2_bagfile_information': information},
                              default_flow_style=False, sort_keys=False)
        partial = self.path / 'metadata.yaml.tmp'
        partial.write_text(text, encoding='utf-8')
        partial.replace(self.path / 'metadata.yaml')

    def abort(self) -> None:
        """Close the file as it is, without summary, footer or ``metadata.yaml``."""
        if self._open:
            self._open = False
            self._stream.close()

    def _information(self) -> dict[str, Any]:
        """Return the contents of ``metadata.yaml`` (``rosbag2_bagfile_information``)."""
        start = self._start_ns if self._count else 0
        duration = self._end_ns - start if self._count else 0
        return {
            'version': 9,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self._count,
            'topics_with_message_count': [{
                'topic_metadata': {
                    'name': channel.topic,
                    'type': channel.msgtype,
                    'serialization_format': channel.serialization_format,
                    'offered_qos_profiles': qos_dicts(channel.offered_qos),
                    'type_description_hash': channel.type_hash,
                },
                'message_count': channel.count,
            } for channel in self._channels.values()],
            'compression_format': '',  # chunks compressed by the storage, not files
            'compression_mode': '',
            'relative_file_paths': [self.file_path.name],
            'files': [{
                'path': self.file_path.name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': self._count,
            }],
            'custom_data': dict(self.custom_data),
            'ros_distro': os.environ.get('ROS_DISTRO') or DEFAULT_ROS_DISTRO,
        }


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
    """Write a rosbag2 bag of CDR messages by topic name, on a thread of its own.

    Callers only queue work, so a node's callbacks never wait for the disk (the CPU work of
    writing shares the GIL still), and a KeyboardInterrupt, raised in the main thread, can never
    tear a record apart. The thread takes the queued messages in batches, every
    :data:`DRAIN_PERIOD_S` (or at once for a flush or the close), rather than being woken for
    each one.

    Parameters
    ----------
    path : str or Path
        Bag directory to create; it must not exist.
    typestore : Typestore or None
        Where message types are defined (default:
        :func:`~exo_has_common.bags.definitions.default_typestore`).
    compress : bool
        Compress each chunk with zstd (smaller files, more CPU).

    Raises
    ------
    BagError
        If the directory exists or cannot be created.

    """

    def __init__(self, path: str | Path, *, typestore: Typestore | None = None,
                 compress: bool = False) -> None:
        self._writer = Rosbag2Writer(path, compress=compress)
        self.path = self._writer.path
        self._typestore = typestore if typestore is not None else default_typestore()
        self._topics: dict[str, str] = {}
        self._channels: dict[str, int] = {}  # the writing thread's
        # deque.append and popleft are atomic: the callers' side needs no lock.
        self._queue: deque[_Command] = deque()
        self._wake = threading.Event()
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
        written, channels = self._writer.counts, dict(self._channels)
        return {topic: written.get(channels.get(topic, 0), 0) for topic in self._topics}

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
        name = normalize_type_name(msgtype)
        self._topics[topic] = name
        self._queue.append(_AddTopic(topic, name, definition, type_hash, tuple(offered_qos)))

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
        self._queue.append((topic, timestamp_ns, bytes(data)))

    def flush(self, wait: bool = False) -> None:
        """Put every message queued so far on disk, as a complete chunk, and sync the file.

        A process killed afterwards loses none of these messages (``exo-has bag recover``).

        Parameters
        ----------
        wait : bool
            Return only once it is done.

        """
        self._check_usable()
        done = threading.Event() if wait else None
        self._queue.append(_Flush(done))
        self._wake.set()
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
            self._queue.append(_Close())
            self._wake.set()
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
        queue, wake, channels = self._queue, self._wake, self._channels
        write = self._writer.write
        while True:
            wake.wait(DRAIN_PERIOD_S)
            wake.clear()  # before draining: a command queued from now on is drained next time
            while queue:
                item = queue.popleft()
                if type(item) is tuple and self._error is None:  # a message: the common case
                    try:
                        write(channels[item[0]], item[1], item[2])
                    except Exception as exc:  # disk full, say: reported to the caller
                        self._error = exc
                elif not self._handle(item):
                    return

    def _handle(self, item: _Command) -> bool:
        """Carry out one queued command; return False once the bag is closed."""
        writer = self._writer
        try:
            if isinstance(item, tuple):
                pass  # a message after a failure: dropped, the failure is reported
            elif isinstance(item, _AddTopic):
                if self._error is None:
                    self._channels[item.topic] = writer.add_channel(
                        item.topic, item.msgtype, item.definition, item.type_hash, item.qos)
            elif isinstance(item, _Flush):
                if self._error is None:
                    writer.flush()
                if item.done is not None:
                    item.done.set()
            else:
                writer.close()
                return False
        except Exception as exc:  # disk full, say: reported to the caller, not lost
            if self._error is None:
                self._error = exc
            if isinstance(item, _Close):
                writer.abort()
                return False
        return True

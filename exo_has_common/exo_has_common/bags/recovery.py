"""Recovering a bag whose recorder was killed: a complete bag of every message written whole.

The ``.mcap`` files are read record by record (:class:`~exo_has_common.bags.records.
McapRecordReader`); every message whose record was written whole is kept, in file order, on the
topics, types, definitions and QoS the file records, and written to a new complete bag (one
``.mcap`` with summary and footer, and ``metadata.yaml``). In place, the originals are kept
beside it as ``*.orig``.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Channel
from rosbags.rosbag2 import ReaderError

from exo_has_common.bags.definitions import definition_hash
from exo_has_common.bags.qos import parse_qos
from exo_has_common.bags.reader import bag_topics
from exo_has_common.bags.records import MCAP_MAGIC, McapRecordReader
from exo_has_common.bags.writer import Rosbag2Writer
from exo_has_common.errors import (
    BagError,
    BagNotFoundError,
    MalformedBagError,
    UnknownMessageTypeError,
)


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


def recover_bag(path: str | Path, output: str | Path | None = None) -> RecoveryReport:
    """Rewrite a bag whose writer was killed as a complete one, with all it can read.

    The ``.mcap`` files are read record by record (:class:`McapRecordReader`): every message
    whose record was written whole is kept, in file order, on the topics, types, definitions
    and QoS the file records; reading stops at the first torn record. The result is a complete
    rosbag2 directory (one ``.mcap`` with summary and footer, and ``metadata.yaml``).

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
    writer = Rosbag2Writer(target)
    try:
        writer.custom_data['exo_has.recovered_from'] = ', '.join(str(f) for f in files)
        by_key: dict[tuple[str, str, str, str], int] = {}
        for file in files:
            reader = McapRecordReader(file)
            channels: dict[int, tuple[int, str]] = {}  # channel in the file: in the bag, topic
            for record in reader.records():
                if isinstance(record, Channel):
                    channel = _channel_for(writer, record, reader, by_key, report)
                    if channel is not None:
                        channels[record.id] = (channel, record.topic)
                        report.messages.setdefault(record.topic, 0)
                    continue
                known = channels.get(record.channel_id)
                if known is None:
                    continue
                writer.write(known[0], record.log_time, record.data)
                report.messages[known[1]] += 1
                report.start_ns = record.log_time if not report.start_ns \
                    else min(report.start_ns, record.log_time)
                report.end_ns = max(report.end_ns, record.log_time)
            report.chunks += reader.chunks
            report.salvaged += reader.salvaged
            report.file_bytes += reader.size
            report.lost_bytes += reader.size - reader.good_until
            if not reader.complete:
                report.stop_reasons.append(f'{file.name}: {reader.stop_reason}')
            report.problems += [f'{file.name}: {bad}' for bad in reader.bad_chunks]
        writer.custom_data['exo_has.lost_bytes'] = str(report.lost_bytes)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def _channel_for(writer: Rosbag2Writer, channel: Channel, reader: McapRecordReader,
                 by_key: dict[tuple[str, str, str, str], int],
                 report: RecoveryReport) -> int | None:
    """Return the recovered bag's channel for a channel of the file, adding it if new."""
    schema = reader.schemas.get(channel.schema_id)
    if schema is None:
        report.problems.append(f'channel {channel.topic!r} has no schema: its messages are '
                               'left out (a rosbag2 topic needs a type)')
        return None
    qos_text = channel.metadata.get('offered_qos_profiles', '')
    key = (channel.topic, schema.name, channel.message_encoding, qos_text)
    known = by_key.get(key)
    if known is not None:
        return known
    try:
        definition = schema.data.decode('utf-8')
        # rosbag2 (Jazzy) and our writer give the hash; older writers leave it to be computed.
        type_hash = channel.metadata.get('topic_type_hash') \
            or definition_hash(schema.name, definition)
        qos = parse_qos(qos_text) if qos_text else []
    except (UnknownMessageTypeError, UnicodeDecodeError, ReaderError) as exc:
        report.problems.append(f'channel {channel.topic!r} ({schema.name}) cannot be '
                               f'rewritten, its messages are left out: {exc}')
        return None
    added = writer.add_channel(channel.topic, schema.name, definition, type_hash, qos,
                               channel.message_encoding)
    by_key[key] = added
    return added

"""Reading an MCAP file record by record, as far as it was written: a killed writer's file.

Such a file has no summary and no footer, so the readers that start from the summary (rosbags',
``mcap``'s ``make_reader``) refuse it. :class:`McapRecordReader` reads it front to back with
``mcap``'s record reader (``mcap.stream_reader.StreamReader``) over a stream that gives every
read whole or raises, so that a record the file ends inside of (torn) stops the reading instead
of being taken short; each chunk is then decompressed and checked (size and CRC) and its
records read the same way.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from io import BytesIO
from pathlib import Path
from typing import IO, BinaryIO, cast

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError, RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import CRCValidationError, StreamReader, get_chunk_data_stream

from exo_has_common.errors import BagNotFoundError, MalformedBagError

#: The bytes an MCAP file starts and ends with.
MCAP_MAGIC = b'\x89MCAP0\r\n'

_RECORD_HEAD = 9  # opcode (1 byte) and content length (8 bytes)
_U64 = struct.Struct('<Q')
#: What a malformed record can make ``mcap``'s record classes raise.
_MALFORMED = (McapError, UnicodeDecodeError, ValueError, struct.error)


class _ShortReadError(Exception):
    """A read that the stream ends inside of."""

    def __init__(self, position: int, wanted: int, available: int) -> None:
        super().__init__(f'{wanted} bytes wanted at byte {position}, {available} there')
        self.position = position
        self.available = available


class _WholeReads:
    """A binary stream whose every read gives all the bytes asked for, or raises."""

    def __init__(self, stream: BinaryIO, position: int = 0) -> None:
        self._stream = stream
        #: Bytes read so far, from where the stream was given.
        self.position = position

    def read(self, size: int = -1) -> bytes:
        data = self._stream.read(size)
        if 0 <= size != len(data):
            raise _ShortReadError(self.position, size, len(data))
        self.position += len(data)
        return data


def _record_reader(source: _WholeReads, size: int, emit_chunks: bool) -> Iterator[object]:
    # No record can be longer than the file: a longer length is a torn or corrupt record, not
    # one to allocate memory for.
    return iter(StreamReader(cast('IO[bytes]', source), skip_magic=True,
                             emit_chunks=emit_chunks, record_size_limit=size).records)


def _chunk_records(data: bytes) -> tuple[list[Schema | Channel | Message], int, bool]:
    """Read a chunk's records: those read whole, the offset after them, and whether all were."""
    source = _WholeReads(BytesIO(data))
    records: list[Schema | Channel | Message] = []
    whole = 0
    try:
        for record in _record_reader(source, len(data), emit_chunks=False):
            if isinstance(record, Schema | Channel | Message):
                records.append(record)
            whole = source.position
    except _ShortReadError as short:
        return records, whole, short.available == 0 and short.position == whole == len(data)
    except _MALFORMED:
        return records, whole, False
    return records, whole, True


class McapRecordReader:
    """Read an MCAP file front to back, record by record, as far as it was written.

    Needs neither summary nor footer, so it reads the file of a writer that was killed: it
    stops at the first record the file ends inside of (torn) or that is malformed, and says so
    in :attr:`stop_reason`. From an uncompressed chunk that is torn it still takes the records
    written whole. A chunk whose decompression, size or CRC check fails is skipped (noted in
    :attr:`bad_chunks`), the records after it are read.

    Parameters
    ----------
    path : Path
        The ``.mcap`` file.

    """

    def __init__(self, path: Path) -> None:
        self.path = path
        #: Bytes of the file.
        self.size = 0
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
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

    def records(self) -> Iterator[Channel | Message]:
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
            self.size = file.seek(0, 2)
            file.seek(0)
            if self.size == 0:
                msg = f'{self.path} is empty: its writer never wrote to it'
                raise MalformedBagError(msg)
            head = file.read(len(MCAP_MAGIC))
            if head != MCAP_MAGIC:
                if len(head) < len(MCAP_MAGIC) and MCAP_MAGIC.startswith(head):
                    self.stop_reason = f'the file ends inside the magic, after {self.size} bytes'
                    return
                msg = f'{self.path} is not an MCAP file: it starts with {head!r}'
                raise MalformedBagError(msg)
            yield from self._read(file)

    def _read(self, file: BinaryIO) -> Iterator[Channel | Message]:
        source = _WholeReads(file, len(MCAP_MAGIC))
        records = _record_reader(source, self.size, emit_chunks=True)
        self.good_until = source.position
        while True:
            try:
                record = next(records)
            except (_ShortReadError, RecordLengthLimitExceeded):
                yield from self._stop_at_torn_record(file)
                return
            except _MALFORMED as exc:
                self.stop_reason = f'the record at byte {self.good_until} is malformed ({exc})'
                return
            except StopIteration:
                return
            if isinstance(record, Chunk):
                yield from self._chunk(record, self.good_until)
            elif isinstance(record, DataEnd | Footer):
                self.complete = True
                self.good_until = self.size
                self.stop_reason = 'the data section is complete'
                return
            elif isinstance(record, Schema | Channel | Message):
                yield from self._plain([record])
            self.good_until = source.position

    def _stop_at_torn_record(self, file: BinaryIO) -> Iterator[Channel | Message]:
        """Say why reading stopped at :attr:`good_until`; salvage a torn chunk's records."""
        start = self.good_until
        file.seek(start)
        head = file.read(_RECORD_HEAD)
        if not head:
            self.stop_reason = (f'the file ends after the record ending at byte {start} (the '
                                'writer never wrote the summary and footer)')
            return
        if len(head) < _RECORD_HEAD:
            self.stop_reason = f'a record starting at byte {start} is torn'
            return
        opcode, length = head[0], int(_U64.unpack_from(head, 1)[0])
        if opcode == 0:
            self.stop_reason = f'bytes from {start} on are not records (opcode 0)'
            return
        try:
            name = Opcode(opcode).name.replace('_', ' ').title().replace(' ', '')
        except ValueError:
            name = f'opcode 0x{opcode:02x}'
        needed = _RECORD_HEAD + length
        if start + needed <= self.size:
            self.stop_reason = f'the records from byte {start} on are torn or unreadable'
            return
        self.stop_reason = (f'the {name} record at byte {start} is torn: it needs {needed} '
                            f'bytes, the file has {self.size - start}')
        if opcode == Opcode.CHUNK:
            yield from self._salvage(file.read(), start)

    def _chunk(self, chunk: Chunk, position: int) -> Iterator[Channel | Message]:
        try:
            stream, size = get_chunk_data_stream(chunk, validate_crc=True)
            data = stream.read(size)
        except CRCValidationError:
            self.bad_chunks.append(f'the chunk at byte {position} fails its size or CRC check')
            return
        except Exception as exc:  # each decompressor raises errors of its own
            self.bad_chunks.append(f'the chunk at byte {position} does not decompress ({exc})')
            return
        if len(data) != chunk.uncompressed_size:
            self.bad_chunks.append(f'the chunk at byte {position} fails its size or CRC check')
            return
        records, _, whole = _chunk_records(data)
        if not whole:
            self.bad_chunks.append(f'the chunk at byte {position} ends in a torn or malformed '
                                   'record: the records before it are kept')
        self.chunks += 1
        yield from self._plain(records)

    def _salvage(self, partial: bytes, position: int) -> Iterator[Channel | Message]:
        """Take the records written whole of a torn, uncompressed chunk."""
        fields = ReadDataStream(cast('IO[bytes]', _WholeReads(BytesIO(partial))))
        try:
            for read in (fields.read8, fields.read8, fields.read8, fields.read4):
                read()  # start and end times, uncompressed size and CRC: not needed
            compression = fields.read_prefixed_string()
            fields.read8()
        except (_ShortReadError, UnicodeDecodeError):
            return
        if compression:
            self.stop_reason += f' ({compression} chunk: its records cannot be salvaged)'
            return
        records, whole, _ = _chunk_records(partial[fields.count:])
        if records:
            self.good_until = position + _RECORD_HEAD + fields.count + whole
        self.salvaged += sum(isinstance(record, Message) for record in records)
        yield from self._plain(records)

    def _plain(self, records: list[Schema | Channel | Message]) -> Iterator[Channel | Message]:
        for record in records:
            if isinstance(record, Schema):
                self.schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                if record.id not in self.channels:
                    self.channels[record.id] = record
                    yield record
            else:
                yield record

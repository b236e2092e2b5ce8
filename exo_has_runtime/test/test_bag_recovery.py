import signal
import struct
import subprocess
import sys
import tempfile
import zlib

import lz4.frame
import pytest
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import JointState

from exo_has_common.bag import BagWriter, McapRecordReader, read_messages, recover_bag
from exo_has_common.errors import BagError, BagNotFoundError, MalformedBagError, UnfinishedBagError
from exo_has_msgs.msg import HasCommand
from exo_has_runtime.processes import tethered
from exo_has_runtime.recording import replay_qos

T0_NS = 1_700_000_000_000_000_000
COMMAND, JOINTS = 'exo_has_msgs/msg/HasCommand', 'sensor_msgs/msg/JointState'


def write_numbered_bag(path, count, flush_every, compress=False):
    """Write ``count`` messages numbered by value, a chunk every ``flush_every``."""
    expected = []
    with BagWriter(path, compress=compress) as writer:
        writer.add_topic('/cmd', COMMAND)
        writer.add_topic('/joints', JOINTS)
        for i in range(count):
            topic, message = ('/cmd', HasCommand(motor_speed=float(i))) if i % 3 \
                else ('/joints', JointState(name=['left_hip'], position=[float(i)]))
            data = serialize_message(message)
            writer.write(topic, T0_NS + i * 1_000_000, data)
            expected.append((topic, T0_NS + i * 1_000_000, data))
            if (i + 1) % flush_every == 0:
                writer.flush(wait=True)
    return expected


def read_all(path):
    with read_messages(path) as messages:
        return [(m.topic, m.timestamp_ns, m.data) for m in messages]


def mcap_of(path):
    return next(path.glob('*.mcap'))


@pytest.mark.parametrize('cut', ['inside the magic', 'after the header', 'inside chunk 1',
                                 'after chunk 2', 'inside chunk 4', 'inside the summary'])
def test_a_bag_truncated_anywhere_is_recovered_up_to_its_last_whole_record(tmp_path, cut):
    expected = write_numbered_bag(tmp_path / 'whole', 60, flush_every=12)
    data = mcap_of(tmp_path / 'whole').read_bytes()
    # Where each message's record ends in the file (its CDR bytes end it, and are unique).
    ends = [data.index(message) + len(message) for _, _, message in expected]
    chunk_ends = [ends[i] for i in range(11, 60, 12)]
    header_end = 8 + 9 + int.from_bytes(data[9:17], 'little')
    offset = {'inside the magic': 5, 'after the header': header_end,
              'inside chunk 1': (ends[3] + ends[4]) // 2, 'after chunk 2': chunk_ends[1] + 9,
              'inside chunk 4': ends[40] + 3, 'inside the summary': len(data) - 50}[cut]
    torn = tmp_path / 'torn'
    torn.mkdir()
    (torn / 'torn.mcap').write_bytes(data[:offset])
    with pytest.raises(UnfinishedBagError, match='exo-has bag recover'):
        read_all(torn)

    report = recover_bag(torn)

    kept = [message for message, end in zip(expected, ends, strict=True) if end <= offset]
    assert read_all(torn) == kept
    assert report.message_count == len(kept)
    assert (torn / 'torn.mcap.orig').read_bytes() == data[:offset]
    with Reader(torn) as reader:  # rosbags opens it: summary, footer and metadata are there
        assert reader.message_count == len(kept)
        assert {c.topic for c in reader.connections} <= {'/cmd', '/joints'}
    described = report.describe()
    assert f'recovered {len(kept)} messages' in described
    if cut == 'inside the summary':
        assert report.lost_bytes == 0 and 'lost: no message' in described
    elif cut != 'after the header':
        read_whole = max([8 if offset >= 8 else 0, *(e for e in ends if e <= offset)])
        assert report.lost_bytes == offset - read_whole
        assert f'lost: the last {report.lost_bytes} of {offset} bytes' in described
    assert recover_bag(torn).already_complete  # a second recovery leaves it alone


def test_the_recovered_bag_keeps_each_topics_type_definition_and_offered_qos(tmp_path):
    write_numbered_bag(tmp_path / 'whole', 24, flush_every=12)
    data = mcap_of(tmp_path / 'whole').read_bytes()
    (tmp_path / 'torn.mcap').write_bytes(data[:len(data) // 2])
    with (tmp_path / 'whole' / 'whole.mcap').open('rb') as stream:
        original = make_reader(stream).get_summary()

    recover_bag(tmp_path / 'torn.mcap', tmp_path / 'recovered')

    with mcap_of(tmp_path / 'recovered').open('rb') as stream:
        recovered = make_reader(stream).get_summary()
    assert sorted((s.name, s.data) for s in recovered.schemas.values()) == \
        sorted((s.name, s.data) for s in original.schemas.values())
    assert sorted((c.topic, c.message_encoding, sorted(c.metadata.items()))
                  for c in recovered.channels.values()) == \
        sorted((c.topic, c.message_encoding, sorted(c.metadata.items()))
               for c in original.channels.values())


def test_a_compressed_bag_is_recovered_up_to_its_last_whole_chunk(tmp_path):
    expected = write_numbered_bag(tmp_path / 'whole', 48, flush_every=12, compress=True)
    data = mcap_of(tmp_path / 'whole').read_bytes()
    with mcap_of(tmp_path / 'whole').open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    chunk_ends = [c.chunk_start_offset + c.chunk_length for c in chunks]
    assert len(chunk_ends) == 4 and all(c.compression == 'zstd' for c in chunks)
    (tmp_path / 'torn.mcap').write_bytes(data[:chunk_ends[2] - 10])

    report = recover_bag(tmp_path / 'torn.mcap', tmp_path / 'recovered')

    assert read_all(tmp_path / 'recovered') == expected[:24]
    assert report.chunks == 2 and report.salvaged == 0
    assert 'zstd chunk: its records cannot be salvaged' in report.describe()


def lz4_chunks(data, bad_crc_chunk):
    """Rewrite an uncompressed MCAP file's chunks with lz4 and a CRC; drop its summary."""
    out, position, index = bytearray(data[:8]), 8, 0
    while data[position] != 0x0F:  # DataEnd: what follows is the summary
        opcode = data[position]
        length = int.from_bytes(data[position + 1:position + 9], 'little')
        content = data[position + 9:position + 9 + length]
        if opcode == 0x06:
            start, end, size, _ = struct.unpack_from('<QQQI', content)
            records = content[28 + 4 + 8:]  # after the (empty) compression and records length
            packed = lz4.frame.compress(records)
            crc = zlib.crc32(records) ^ (index == bad_crc_chunk)
            content = struct.pack('<QQQII', start, end, size, crc, 3) + b'lz4' + \
                struct.pack('<Q', len(packed)) + packed
            index += 1
        out += bytes([opcode]) + struct.pack('<Q', len(content)) + content
        position += 9 + length
    return bytes(out)


def test_lz4_chunks_are_read_and_one_failing_its_crc_is_left_out_alone(tmp_path):
    expected = write_numbered_bag(tmp_path / 'whole', 48, flush_every=12)
    (tmp_path / 'lz4.mcap').write_bytes(lz4_chunks(mcap_of(tmp_path / 'whole').read_bytes(), 1))

    report = recover_bag(tmp_path / 'lz4.mcap', tmp_path / 'recovered')

    assert read_all(tmp_path / 'recovered') == expected[:12] + expected[24:]
    assert report.chunks == 3 and report.lost_bytes == 0
    assert 'fails its size or CRC check' in report.describe()


def test_a_chunk_whose_bytes_were_damaged_on_disk_is_told_by_its_crc_and_left_out(tmp_path):
    expected = write_numbered_bag(tmp_path / 'whole', 36, flush_every=12)
    data = bytearray(mcap_of(tmp_path / 'whole').read_bytes())
    at = data.index(expected[15][2])
    data[at + 10] ^= 0xFF  # inside chunk 2, the record framing intact
    (tmp_path / 'damaged.mcap').write_bytes(bytes(data))

    report = recover_bag(tmp_path / 'damaged.mcap', tmp_path / 'recovered')

    assert read_all(tmp_path / 'recovered') == expected[:12] + expected[24:]
    assert 'the chunk at byte' in report.describe() and 'CRC' in report.describe()


@pytest.mark.process
def test_a_writer_killed_mid_write_is_recovered_with_every_message_it_flushed(tmp_path):
    script = (
        'import sys, time\n'
        'from rclpy.serialization import serialize_message\n'
        'from exo_has_msgs.msg import HasCommand\n'
        'from exo_has_common.bag import BagWriter\n'
        'writer = BagWriter(sys.argv[1])\n'
        'writer.add_topic("/cmd", "exo_has_msgs/msg/HasCommand")\n'
        'for i in range(10**9):\n'
        '    writer.write("/cmd", i, serialize_message(HasCommand(motor_speed=float(i))))\n'
        '    if i % 100 == 99:\n'
        '        writer.flush(wait=True)\n'
        '        print("FLUSHED", i + 1, flush=True)\n'
        '        time.sleep(0.01)\n')
    process = subprocess.Popen(tethered([sys.executable, '-c', script, str(tmp_path / 'bag')]),
                               stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())
    try:
        flushed = [int(process.stdout.readline().split()[1]) for _ in range(5)][-1]
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
        process.stdout.close()
    assert not (tmp_path / 'bag' / 'metadata.yaml').exists()

    report = recover_bag(tmp_path / 'bag')

    recovered = read_all(tmp_path / 'bag')
    assert report.message_count == len(recovered) >= flushed
    assert [deserialize_message(data, HasCommand).motor_speed for _, _, data in recovered] == \
        [float(i) for i in range(len(recovered))]
    assert replay_qos(()).reliable  # the recovered topic has no QoS record: replay's default


def test_recovery_of_what_is_no_bag_fails_naming_the_problem(tmp_path):
    with pytest.raises(BagNotFoundError, match=r'no bag at .*nowhere'):
        recover_bag(tmp_path / 'nowhere')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(MalformedBagError, match=r'holds no \.mcap file'):
        recover_bag(tmp_path / 'empty')
    (tmp_path / 'text').mkdir()
    (tmp_path / 'text' / 'text.mcap').write_text('not a bag at all')
    with pytest.raises(MalformedBagError, match=r"not an MCAP file: it starts with b'not a ba'"):
        recover_bag(tmp_path / 'text')
    (tmp_path / 'zero').mkdir()
    (tmp_path / 'zero' / 'zero.mcap').write_bytes(b'')
    with pytest.raises(MalformedBagError, match='is empty: its writer never wrote to it'):
        recover_bag(tmp_path / 'zero')
    assert not (tmp_path / 'zero' / '.recovering').exists()
    write_numbered_bag(tmp_path / 'bag', 3, flush_every=10)
    with pytest.raises(BagError, match='exists already: give another output'):
        recover_bag(tmp_path / 'bag' / 'bag.mcap', tmp_path / 'bag')


def test_a_file_ending_in_zeros_or_garbage_is_read_up_to_its_last_whole_record(tmp_path):
    expected = write_numbered_bag(tmp_path / 'whole', 24, flush_every=12)
    data = mcap_of(tmp_path / 'whole').read_bytes()
    end_of_chunk_1 = data.index(expected[11][2]) + len(expected[11][2])
    # What a power loss may leave: the file's last blocks allocated but never written.
    (tmp_path / 'zeros.mcap').write_bytes(data[:end_of_chunk_1] + bytes(4096))
    reader = McapRecordReader(tmp_path / 'zeros.mcap')
    assert sum(1 for record in reader.records() if hasattr(record, 'log_time')) == 12
    assert 'not records (opcode 0)' in reader.stop_reason and not reader.complete
    # A record claiming more bytes than the file has: torn, reading stops before it.
    (tmp_path / 'long.mcap').write_bytes(data[:end_of_chunk_1] + b'\x06' + b'\xff' * 8)
    reader = McapRecordReader(tmp_path / 'long.mcap')
    assert sum(1 for record in reader.records() if hasattr(record, 'log_time')) == 12
    assert 'Chunk record at byte' in reader.stop_reason and 'is torn' in reader.stop_reason
    assert reader.good_until == end_of_chunk_1


def test_a_closed_bag_whose_file_was_cut_short_is_recovered_in_place(tmp_path):
    expected = write_numbered_bag(tmp_path / 'bag', 30, flush_every=10)
    data = mcap_of(tmp_path / 'bag').read_bytes()
    mcap_of(tmp_path / 'bag').write_bytes(data[:-100])  # metadata.yaml is there, the footer not

    report = recover_bag(tmp_path / 'bag')

    assert not report.already_complete and report.message_count == 30
    assert read_all(tmp_path / 'bag') == expected
    assert sorted(p.name for p in (tmp_path / 'bag').iterdir()) == [
        'bag.mcap', 'bag.mcap.orig', 'metadata.yaml', 'metadata.yaml.orig']

import math
import signal
import struct
import subprocess
import sys
import tempfile
import zlib
from datetime import datetime
from pathlib import Path

import lz4.frame
import pytest
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from exo_has_runtime import bag as bag_module
from exo_has_runtime.bag import (
    BagWriter,
    McapScanner,
    bag_summary,
    bag_topics,
    format_summary,
    message_definition,
    read_messages,
    recover_bag,
)
from exo_has_runtime.cli import subcommands
from exo_has_runtime.errors import (
    BagError,
    BagNotFoundError,
    MalformedBagError,
    ReplayError,
    UnfinishedBagError,
    UnknownMessageTypeError,
)
from exo_has_runtime.recording import (
    RECORD_DEPTH,
    QosChoice,
    bag_path,
    check_rate,
    replay_offset_ns,
    replay_qos,
    select_replay_topics,
    subscription_qos,
    topics_to_record,
    weakened_qos,
)
from exo_has_runtime.replay import main as replay_main
from exo_has_runtime.standalone.messages import default_registry
from exo_has_runtime.standalone.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

REGISTRY = default_registry()
HasCommand = REGISTRY.get_message('exo_has_msgs/msg/HasCommand')
HasState = REGISTRY.get_message('exo_has_msgs/msg/HasState')
SafetyEvent = REGISTRY.get_message('exo_has_msgs/msg/SafetyEvent')
JointState = REGISTRY.get_message('sensor_msgs/msg/JointState')
MSG_DIR = Path(__file__).resolve().parents[2] / 'exo_has_msgs' / 'msg'
T0_NS = 1_700_000_000_000_000_000
RELIABLE_VOLATILE = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE,
                        QosDurability.VOLATILE, QosTime(0, 0), QosTime(0, 0),
                        QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


def cdr(message):
    return REGISTRY.serialize(message)


def sample_messages():
    """One message of each type, with values that show a field coming back wrong."""
    command = HasCommand(joint='left_hip', motor_speed=-418.88, enable=True)
    command.header.stamp.sec, command.header.stamp.nanosec = 12, 345
    state = HasState(joint='right_knee', position=0.0421, velocity=-0.01, pressure_a=4.2e6,
                     pressure_b=1.5e5, motor_speed=100.0, motor_speed_command=101.0,
                     motor_current=math.nan, load_force=-250.0,
                     valve_mode=HasState.VALVE_RELIEF)
    event = SafetyEvent(joint='', kind=SafetyEvent.KIND_OVER_PRESSURE,
                        severity=SafetyEvent.SEVERITY_FATAL, value=2.1e7, limit=2.0e7,
                        latched=True, text='over pressure: Überdruck 21 MPa')
    joints = JointState(name=['left_hip', 'left_knee'], position=[0.1, -0.2],
                        velocity=[1.0, 2.0], effort=[])
    return [('/left_hip/has_command', 'exo_has_msgs/msg/HasCommand', command),
            ('/right_knee/has_state', 'exo_has_msgs/msg/HasState', state),
            ('/safety_events', 'exo_has_msgs/msg/SafetyEvent', event),
            ('/joint_reference', 'sensor_msgs/msg/JointState', joints)]


def write_numbered_bag(path, count, flush_every, compress=False):
    """Write ``count`` HasCommands numbered by motor_speed, a chunk every ``flush_every``."""
    expected = []
    with BagWriter(path, compress=compress) as writer:
        writer.add_topic('/cmd', 'exo_has_msgs/msg/HasCommand', [RELIABLE_VOLATILE])
        writer.add_topic('/joints', 'sensor_msgs/msg/JointState')
        for i in range(count):
            topic, message = ('/cmd', HasCommand(motor_speed=float(i))) if i % 3 \
                else ('/joints', JointState(name=['left_hip'], position=[float(i)]))
            data = cdr(message)
            writer.write(topic, T0_NS + i * 1_000_000, data)
            expected.append((topic, T0_NS + i * 1_000_000, data))
            if (i + 1) % flush_every == 0:
                writer.flush(wait=True)
    return expected


def read_all(path):
    with read_messages(path) as messages:
        return [(m.topic, m.timestamp_ns, m.data) for m in messages]


def mcap_of(path):
    return next(Path(path).glob('*.mcap'))


def test_messages_of_the_three_exo_has_types_and_joint_state_come_back_byte_for_byte(tmp_path):
    written = []
    with BagWriter(tmp_path / 'bag') as writer:
        for topic, msgtype, _ in sample_messages():
            writer.add_topic(topic, msgtype, [RELIABLE_VOLATILE])
        for i, (topic, msgtype, message) in enumerate(sample_messages() * 3):
            written.append((topic, msgtype, T0_NS + i * 5_000_000, cdr(message)))
            writer.write(topic, T0_NS + i * 5_000_000, cdr(message))
    assert writer.counts == {topic: 3 for topic, _, _ in sample_messages()}
    assert sorted((tmp_path / 'bag').iterdir()) == [tmp_path / 'bag' / 'bag.mcap',
                                                    tmp_path / 'bag' / 'metadata.yaml']
    with read_messages(tmp_path / 'bag') as messages:
        assert [tuple(m) for m in messages] == written
    # A reader without our packages decodes them from the definitions embedded in the bag.
    with Reader(tmp_path / 'bag') as reader:
        foreign = get_typestore(Stores.EMPTY)
        for connection in reader.connections:
            foreign.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
        decoded = {c.topic: foreign.deserialize_cdr(data, c.msgtype)
                   for c, _, data in reader.messages()}
    assert decoded['/safety_events'].text == 'over pressure: Überdruck 21 MPa'
    assert decoded['/right_knee/has_state'].valve_mode == HasState.VALVE_RELIEF
    assert math.isnan(decoded['/right_knee/has_state'].motor_current)
    assert decoded['/joint_reference'].name == ['left_hip', 'left_knee']
    assert decoded['/left_hip/has_command'].header.stamp.nanosec == 345


def test_the_embedded_schema_is_the_message_definition_with_its_nested_types(tmp_path):
    with BagWriter(tmp_path / 'bag') as writer:
        for topic, msgtype, _ in sample_messages():
            writer.add_topic(topic, msgtype)
    scanner = McapScanner(mcap_of(tmp_path / 'bag'))
    list(scanner.records())
    schemas = {schema.name: schema for schema in scanner.schemas.values()}
    for name in ('HasCommand', 'HasState', 'SafetyEvent'):
        schema = schemas[f'exo_has_msgs/msg/{name}']
        assert schema.encoding == 'ros2msg'
        own, *nested = schema.data.decode().split('=' * 80 + '\n')
        assert own == (MSG_DIR / f'{name}.msg').read_text()  # comments (units) included
        assert [section.split('\n', 1)[0] for section in nested] == [
            'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
        definition, type_hash = message_definition(f'exo_has_msgs/msg/{name}')
        assert schema.data.decode() == definition
        assert type_hash == REGISTRY.type_hash(f'exo_has_msgs/msg/{name}')
    joints = schemas['sensor_msgs/msg/JointState'].data.decode()
    assert joints.startswith('std_msgs/Header header\nstring[] name\nfloat64[] position\n')
    parsed = get_types_from_msg(schemas['exo_has_msgs/msg/HasState'].data.decode(),
                                'exo_has_msgs/msg/HasState')
    assert parsed['exo_has_msgs/msg/HasState'] == \
        REGISTRY.typestore.fielddefs['exo_has_msgs/msg/HasState']


def test_a_type_outside_the_workspace_is_found_through_the_ament_index(tmp_path, monkeypatch):
    share = tmp_path / 'prefix' / 'share' / 'vendor_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'Pump.msg').write_text('# A pump.\nstd_msgs/Header header\n'
                                    'float64 speed  # [rad/s]\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'prefix'))
    store = get_typestore(Stores.ROS2_JAZZY)
    definition, type_hash = message_definition('vendor_msgs/msg/Pump', store)
    assert definition.startswith('# A pump.\nstd_msgs/Header header\nfloat64 speed  # [rad/s]\n')
    assert type_hash.startswith('RIHS01_')
    with pytest.raises(UnknownMessageTypeError, match="'vendor_msgs/msg/Valve' is unknown"):
        message_definition('vendor_msgs/msg/Valve', store)


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


def test_a_compressed_bag_is_recovered_up_to_its_last_whole_chunk(tmp_path):
    expected = write_numbered_bag(tmp_path / 'whole', 48, flush_every=12, compress=True)
    data = mcap_of(tmp_path / 'whole').read_bytes()
    with Reader(tmp_path / 'whole') as reader:
        chunks = reader.storage.storages[0].chunks
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


def test_a_writer_killed_mid_write_is_recovered_with_every_message_it_flushed(tmp_path):
    script = (
        'import sys, time\n'
        'from exo_has_runtime.bag import BagWriter\n'
        'from exo_has_runtime.standalone.messages import default_registry\n'
        'registry = default_registry()\n'
        'Command = registry.get_message("exo_has_msgs/msg/HasCommand")\n'
        'writer = BagWriter(sys.argv[1])\n'
        'writer.add_topic("/cmd", "exo_has_msgs/msg/HasCommand")\n'
        'for i in range(10**9):\n'
        '    writer.write("/cmd", i, registry.serialize(Command(motor_speed=float(i))))\n'
        '    if i % 100 == 99:\n'
        '        writer.flush(wait=True)\n'
        '        print("FLUSHED", i + 1, flush=True)\n'
        '        time.sleep(0.01)\n')
    process = subprocess.Popen([sys.executable, '-c', script, str(tmp_path / 'bag')],
                               stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())
    try:
        flushed = [int(process.stdout.readline().split()[1]) for _ in range(5)][-1]
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
    assert not (tmp_path / 'bag' / 'metadata.yaml').exists()

    report = recover_bag(tmp_path / 'bag')

    recovered = read_all(tmp_path / 'bag')
    assert report.message_count == len(recovered) >= flushed
    assert [data for _, _, data in recovered] == [
        cdr(HasCommand(motor_speed=float(i))) for i in range(len(recovered))]


def test_a_missing_bag_an_unfinished_one_and_files_that_are_no_bag_fail_clearly(tmp_path):
    with pytest.raises(BagNotFoundError, match=r'no bag at .*nowhere'):
        read_all(tmp_path / 'nowhere')
    with pytest.raises(BagNotFoundError, match='no bag at'):
        recover_bag(tmp_path / 'nowhere')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(MalformedBagError, match=r'neither metadata\.yaml nor an \.mcap'):
        bag_topics(tmp_path / 'empty')
    with pytest.raises(MalformedBagError, match=r'holds no \.mcap file'):
        recover_bag(tmp_path / 'empty')
    (tmp_path / 'text').mkdir()
    (tmp_path / 'text' / 'text.mcap').write_text('not a bag at all')
    with pytest.raises(MalformedBagError, match=r"not an MCAP file: it starts with b'not a ba'"):
        recover_bag(tmp_path / 'text')
    (tmp_path / 'text' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [')
    with pytest.raises(MalformedBagError, match=r'(?s)cannot read bag .*exo-has bag recover'):
        read_all(tmp_path / 'text')
    write_numbered_bag(tmp_path / 'bag', 3, flush_every=10)
    with pytest.raises(BagError, match='exists already'):
        BagWriter(tmp_path / 'bag')
    with pytest.raises(BagError, match='no topic /nope; its topics: /cmd, /joints'), \
            read_messages(tmp_path / 'bag', ['/nope']):
        pass
    with BagWriter(tmp_path / 'other') as writer, \
            pytest.raises(BagError, match="'/cmd' was not added"):
        writer.write('/cmd', 0, b'')
    with BagWriter(tmp_path / 'third') as writer, \
            pytest.raises(UnknownMessageTypeError, match="'exo_has_msgs/msg/Nothing'"):
        writer.add_topic('/x', 'exo_has_msgs/msg/Nothing')


def test_the_summary_gives_each_topics_type_count_span_and_rate(tmp_path):
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/fast', 'exo_has_msgs/msg/HasState', [RELIABLE_VOLATILE])
        writer.add_topic('/idle', 'std_msgs/msg/Empty')
        for i in range(201):  # 200 Hz for 1 s
            writer.write('/fast', T0_NS + i * 5_000_000, cdr(HasState()))
    summary = bag_summary(tmp_path / 'bag')
    fast, idle = summary.topics
    assert (fast.topic, fast.msgtype, fast.count) == ('/fast', 'exo_has_msgs/msg/HasState', 201)
    assert fast.rate_hz == pytest.approx(200.0) and idle.rate_hz is None and idle.count == 0
    assert summary.duration_s == pytest.approx(1.0) and summary.message_count == 201
    text = format_summary(summary)
    assert 'duration:  1.000 s' in text and 'reliable/volatile' in text
    assert '/fast  exo_has_msgs/msg/HasState       201     200.00' in text


def test_the_bag_command_prints_the_summary_and_recovers(tmp_path, capsys):
    assert {'bag', 'replay'} <= set(subcommands())
    expected = write_numbered_bag(tmp_path / 'whole', 30, flush_every=10)
    assert bag_module.main(['info', str(tmp_path / 'whole')]) == 0
    assert 'messages:  30' in capsys.readouterr().out
    (tmp_path / 'torn').mkdir()
    data = mcap_of(tmp_path / 'whole').read_bytes()
    (tmp_path / 'torn' / 'torn.mcap').write_bytes(data[:len(data) // 2])
    assert bag_module.main(['info', str(tmp_path / 'torn')]) == 1
    assert 'never closed; if its recorder was killed' in capsys.readouterr().err
    out_dir = tmp_path / 'out'
    assert bag_module.main(['recover', str(tmp_path / 'torn'), '--output', str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert out.startswith('recovered ') and str(out_dir) in out
    assert read_all(out_dir) == expected[:len(read_all(out_dir))]
    assert not (tmp_path / 'torn' / 'metadata.yaml').exists()  # --output leaves the source be
    assert bag_module.main(['recover', str(tmp_path / 'torn'), '--output', str(out_dir)]) == 1
    assert 'exists already' in capsys.readouterr().err


def test_the_recorder_asks_for_no_more_qos_than_every_publisher_offers():
    reliable = QoSProfile(depth=10)
    best_effort = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    latched = QoSProfile(depth=2000, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    assert subscription_qos([reliable, reliable]).reliable
    assert not subscription_qos([reliable, best_effort]).reliable
    assert subscription_qos([latched]).transient_local
    assert subscription_qos([latched]).depth == 2000
    choice = subscription_qos([latched, reliable])
    assert not choice.transient_local and choice.depth == RECORD_DEPTH
    assert replay_qos([]) == replay_qos([RELIABLE_VOLATILE]) == QosChoice(True, False, 10)
    # A publisher joining later with less: the subscription is made weaker, never stronger.
    current = QosChoice(True, True, RECORD_DEPTH)
    assert weakened_qos(current, [latched]) is None and weakened_qos(current, []) is None
    assert weakened_qos(current, [latched, reliable]) == QosChoice(True, False, RECORD_DEPTH)
    assert weakened_qos(current, [best_effort]) == QosChoice(False, False, RECORD_DEPTH)
    assert weakened_qos(QosChoice(False, False, RECORD_DEPTH), [latched]) is None


def test_the_recorder_picks_new_single_typed_visible_topics():
    graph = [('/a', ['std_msgs/msg/Empty']), ('/b', ['x/msg/A', 'x/msg/B']),
             ('/ros_discovery_info', ['rmw_dds_common/msg/ParticipantEntitiesInfo']),
             ('/_hidden/c', ['std_msgs/msg/Empty']), ('/d', ['std_msgs/msg/Empty'])]
    assert topics_to_record(graph, None, {'/d'}) == (
        [('/a', 'std_msgs/msg/Empty')], [('/b', ['x/msg/A', 'x/msg/B'])])
    assert topics_to_record(graph, {'/_hidden/c'}, set()) == (
        [('/_hidden/c', 'std_msgs/msg/Empty')], [])
    default = bag_path('', datetime(2026, 3, 4, 5, 6, 7))
    assert default == Path('~/.ros/exo_has_bags/session_20260304_050607').expanduser()
    assert bag_path('~/x', datetime.now()) == Path.home() / 'x'
    assert bag_path('rel', datetime.now()).is_absolute()


def test_replay_timing_scales_with_the_rate_and_bad_options_are_named(tmp_path, capsys):
    assert replay_offset_ns(T0_NS + 1_000_000_000, T0_NS, 2.0) == 500_000_000
    for rate in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ReplayError, match='must be a positive factor'):
            check_rate(rate)
    available = {'/a': 'std_msgs/msg/Empty', '/b': 'std_msgs/msg/Empty'}
    assert select_replay_topics(available, None) == ['/a', '/b']
    assert select_replay_topics(available, ['b']) == ['/b']
    with pytest.raises(ReplayError, match='no topic /c; its topics: /a, /b'):
        select_replay_topics(available, ['/a', '/c'])
    write_numbered_bag(tmp_path / 'bag', 3, flush_every=10)
    for argv, complaint in [([str(tmp_path / 'none')], 'no bag at'),
                            ([str(tmp_path / 'bag'), '--rate', '0'], 'positive factor'),
                            ([str(tmp_path / 'bag'), '--topics', '/x'], 'no topic /x'),
                            ([str(tmp_path / 'bag'), '--delay', '-1'], 'delay must be')]:
        assert replay_main(argv) == 1
        assert complaint in capsys.readouterr().err


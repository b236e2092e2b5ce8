import json
import math
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message, serialize_message
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
from sensor_msgs.msg import JointState

from exo_has_common import bag as bag_module
from exo_has_common.bag import (
    BagWriter,
    bag_summary,
    bag_topics,
    default_typestore,
    format_summary,
    message_definition,
    msg_file,
    read_messages,
)
from exo_has_common.errors import (
    BagError,
    BagNotFoundError,
    MalformedBagError,
    UnfinishedBagError,
    UnknownMessageTypeError,
)
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.cli import subcommands

MSG_DIR = Path(__file__).resolve().parents[2] / 'exo_has_msgs' / 'msg'
T0_NS = 1_700_000_000_000_000_000
RELIABLE_VOLATILE = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE,
                        QosDurability.VOLATILE, QosTime(0, 0), QosTime(0, 0),
                        QosLiveliness.AUTOMATIC, QosTime(0, 0), False)
TYPES = {HasCommand: 'exo_has_msgs/msg/HasCommand', HasState: 'exo_has_msgs/msg/HasState',
         SafetyEvent: 'exo_has_msgs/msg/SafetyEvent', JointState: 'sensor_msgs/msg/JointState'}


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
    # Every sequence filled: rclpy (Fast CDR) pads an empty float64 sequence with 4 more bytes
    # than rosbags' deserializer, used below as a foreign reader, accepts.
    joints = JointState(name=['left_hip', 'left_knee'], position=[0.1, -0.2],
                        velocity=[1.0, 2.0], effort=[0.0, 3.5])
    return [('/left_hip/has_command', command), ('/right_knee/has_state', state),
            ('/safety_events', event), ('/joint_reference', joints)]


def test_messages_of_the_three_exo_has_types_and_joint_state_come_back_byte_for_byte(tmp_path):
    written = []
    with BagWriter(tmp_path / 'bag') as writer:
        for topic, message in sample_messages():
            writer.add_topic(topic, TYPES[type(message)], [RELIABLE_VOLATILE])
        for i, (topic, message) in enumerate(sample_messages() * 3):
            data = serialize_message(message)
            written.append((topic, TYPES[type(message)], T0_NS + i * 5_000_000, data))
            writer.write(topic, T0_NS + i * 5_000_000, data)
    assert writer.counts == {topic: 3 for topic, _ in sample_messages()}
    assert sorted((tmp_path / 'bag').iterdir()) == [tmp_path / 'bag' / 'bag.mcap',
                                                    tmp_path / 'bag' / 'metadata.yaml']
    with read_messages(tmp_path / 'bag') as messages:
        read = [tuple(m) for m in messages]
    assert read == written
    originals = dict(sample_messages())
    for topic, _, _, data in read[:4]:
        again = deserialize_message(data, type(originals[topic]))
        assert repr(again) == repr(originals[topic])  # repr: the NaN compares unequal
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


def test_the_bag_is_rosbag2_mcap_with_full_definitions_qos_and_version_9_metadata(tmp_path):
    with BagWriter(tmp_path / 'bag') as writer:
        for topic, message in sample_messages():
            writer.add_topic(topic, TYPES[type(message)], [RELIABLE_VOLATILE])
            writer.write(topic, T0_NS, serialize_message(message))
    with (tmp_path / 'bag' / 'bag.mcap').open('rb') as stream:  # mcap's own reader opens it
        reader = make_reader(stream)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
    schemas = {schema.name: schema for schema in summary.schemas.values()}
    channels = {channel.topic: channel for channel in summary.channels.values()}
    for name in ('HasCommand', 'HasState', 'SafetyEvent'):
        msgtype = f'exo_has_msgs/msg/{name}'
        schema = schemas[msgtype]
        assert schema.encoding == 'ros2msg'
        own, *nested = schema.data.decode().split('=' * 80 + '\n')
        assert own == (MSG_DIR / f'{name}.msg').read_text()  # comments (units) included
        assert [section.split('\n', 1)[0] for section in nested] == [
            'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
        definition, type_hash = message_definition(msgtype)
        assert schema.data.decode() == definition
        # The hash rosidl generated for the type, as rclpy announces it.
        generated = json.loads(msg_file(msgtype).with_suffix('.json').read_text())
        assert type_hash == generated['type_hashes'][0]['hash_string']
        parsed = get_types_from_msg(schema.data.decode(), msgtype)
        assert parsed[msgtype] == default_typestore().fielddefs[msgtype]
    joints = get_types_from_msg(schemas['sensor_msgs/msg/JointState'].data.decode(),
                                'sensor_msgs/msg/JointState')
    assert joints['sensor_msgs/msg/JointState'] == \
        get_typestore(Stores.ROS2_JAZZY).fielddefs['sensor_msgs/msg/JointState']
    state = channels['/right_knee/has_state']
    assert state.message_encoding == 'cdr'
    assert state.metadata['topic_type_hash'] == message_definition(TYPES[HasState])[1]
    (offered,) = yaml.safe_load(state.metadata['offered_qos_profiles'])
    assert (offered['reliability'], offered['durability'], offered['depth']) == (
        'reliable', 'volatile', 10)
    information = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    information = information['rosbag2_bagfile_information']
    assert (information['version'], information['storage_identifier'],
            information['message_count'], information['relative_file_paths']) == (
        9, 'mcap', 4, ['bag.mcap'])
    topics = {t['topic_metadata']['name']: t for t in information['topics_with_message_count']}
    assert topics['/right_knee/has_state']['topic_metadata']['type_description_hash'] == \
        state.metadata['topic_type_hash']
    assert topics['/safety_events']['topic_metadata']['offered_qos_profiles'][0][
        'reliability'] == 'reliable'


def test_a_type_outside_the_jazzy_set_is_found_through_the_ament_prefixes(tmp_path,
                                                                         monkeypatch):
    share = tmp_path / 'prefix' / 'share' / 'vendor_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'Pump.msg').write_text('# A pump.\nstd_msgs/Header header\n'
                                    'float64 speed  # [rad/s]\n')
    (share / 'Broken.msg').write_text('float64[ speed\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'prefix'))
    store = get_typestore(Stores.ROS2_JAZZY)
    definition, type_hash = message_definition('vendor_msgs/msg/Pump', store)
    assert definition.startswith('# A pump.\nstd_msgs/Header header\nfloat64 speed  # [rad/s]\n')
    assert type_hash.startswith('RIHS01_')
    with pytest.raises(UnknownMessageTypeError, match="'vendor_msgs/msg/Valve' is unknown"):
        message_definition('vendor_msgs/msg/Valve', store)
    with pytest.raises(UnknownMessageTypeError, match=r'Broken\.msg: cannot read message def'):
        message_definition('vendor_msgs/msg/Broken', store)
    with pytest.raises(UnknownMessageTypeError, match="malformed message type name 'Pump'"):
        message_definition('Pump', store)


def write_numbered_bag(path, count):
    with BagWriter(path) as writer:
        writer.add_topic('/cmd', 'exo_has_msgs/msg/HasCommand', [RELIABLE_VOLATILE])
        writer.add_topic('/joints', 'sensor_msgs/msg/JointState')
        for i in range(count):
            writer.write('/cmd', T0_NS + i * 1_000_000,
                         serialize_message(HasCommand(motor_speed=float(i))))


def test_a_missing_bag_an_unfinished_one_and_files_that_are_no_bag_fail_clearly(tmp_path):
    with pytest.raises(BagNotFoundError, match=r'no bag at .*nowhere'), \
            read_messages(tmp_path / 'nowhere'):
        pass
    (tmp_path / 'empty').mkdir()
    with pytest.raises(MalformedBagError, match=r'neither metadata\.yaml nor an \.mcap'):
        bag_topics(tmp_path / 'empty')
    (tmp_path / 'unfinished').mkdir()
    (tmp_path / 'unfinished' / 'unfinished.mcap').write_bytes(b'\x89MCAP0\r\n')
    with pytest.raises(UnfinishedBagError, match=r'never closed.*exo-has bag recover'):
        bag_topics(tmp_path / 'unfinished')
    (tmp_path / 'text').mkdir()
    (tmp_path / 'text' / 'text.mcap').write_text('not a bag at all')
    (tmp_path / 'text' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [')
    with pytest.raises(MalformedBagError, match=r'(?s)cannot read bag .*exo-has bag recover'), \
            read_messages(tmp_path / 'text'):
        pass
    write_numbered_bag(tmp_path / 'bag', 3)
    with pytest.raises(BagError, match='exists already'):
        BagWriter(tmp_path / 'bag')
    with pytest.raises(BagError, match='no topic /nope; its topics: /cmd, /joints'), \
            read_messages(tmp_path / 'bag', ['/nope']):
        pass
    with BagWriter(tmp_path / 'other') as writer, \
            pytest.raises(BagError, match="'/cmd' was not added"):
        writer.write('/cmd', 0, b'')
    with BagWriter(tmp_path / 'third') as writer:
        with pytest.raises(UnknownMessageTypeError, match="'exo_has_msgs/msg/Nothing'"):
            writer.add_topic('/x', 'exo_has_msgs/msg/Nothing')
        writer.add_topic('/y', 'std_msgs/msg/Empty')
        with pytest.raises(BagError, match=r"topic '/y' is in bag .* already"):
            writer.add_topic('/y', 'std_msgs/msg/Empty')
    with pytest.raises(BagError, match='is closed'):
        writer.write('/y', 0, b'')


def test_a_closed_bag_whose_file_was_cut_short_fails_naming_the_bag_and_the_fix(tmp_path):
    write_numbered_bag(tmp_path / 'bag', 50)
    data = (tmp_path / 'bag' / 'bag.mcap').read_bytes()
    (tmp_path / 'bag' / 'bag.mcap').write_bytes(data[:-100])  # the footer and some summary
    with pytest.raises(MalformedBagError, match=r'cannot read bag .*bag: .*exo-has bag recover'), \
            read_messages(tmp_path / 'bag'):
        pass


def test_the_summary_gives_each_topics_type_count_span_and_rate(tmp_path):
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/fast', 'exo_has_msgs/msg/HasState', [RELIABLE_VOLATILE])
        writer.add_topic('/idle', 'std_msgs/msg/Empty')
        for i in range(201):  # 200 Hz for 1 s
            writer.write('/fast', T0_NS + i * 5_000_000, serialize_message(HasState()))
    summary = bag_summary(tmp_path / 'bag')
    fast, idle = summary.topics
    assert (fast.topic, fast.msgtype, fast.count) == ('/fast', 'exo_has_msgs/msg/HasState', 201)
    assert fast.rate_hz == pytest.approx(200.0) and idle.rate_hz is None and idle.count == 0
    assert summary.duration_s == pytest.approx(1.0) and summary.message_count == 201
    text = format_summary(summary)
    assert 'duration:  1.000 s' in text and 'reliable/volatile' in text
    assert '/fast  exo_has_msgs/msg/HasState       201     200.00' in text
    assert summary.gaps == [] and 'gaps:      none' in text


def test_the_summary_lists_where_a_steady_topic_stopped_and_how_much_it_likely_lost(tmp_path):
    times = [T0_NS + i * 5_000_000 for i in range(400)]  # 2 s at 200 Hz ...
    times += [times[-1] + 2_000_000_000 + i * 5_000_000 for i in range(1, 200)]  # ... 2 s out
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/fast', 'exo_has_msgs/msg/HasState')
        writer.add_topic('/events', 'exo_has_msgs/msg/SafetyEvent')
        for t in times:
            writer.write('/fast', t, serialize_message(HasState()))
        for t in (T0_NS, T0_NS + 3_000_000_000):  # sporadic: never a gap
            writer.write('/events', t, serialize_message(SafetyEvent()))
    summary = bag_summary(tmp_path / 'bag')
    (gap,) = summary.gaps
    assert (gap.topic, gap.start_ns, gap.end_ns) == ('/fast', times[399], times[400])
    assert gap.seconds == pytest.approx(2.005) and gap.missing == 400
    text = format_summary(summary)
    assert 'gaps:      1' in text
    assert '/fast: 2.005 s without a message from' in text
    assert 'about 400 missing at 200 Hz' in text


def test_the_bag_command_prints_the_summary_and_recovers(tmp_path, capsys):
    assert {'bag', 'replay'} <= set(subcommands())
    write_numbered_bag(tmp_path / 'whole', 30)
    assert bag_module.main(['info', str(tmp_path / 'whole')]) == 0
    assert 'messages:  30' in capsys.readouterr().out
    (tmp_path / 'torn').mkdir()
    data = (tmp_path / 'whole' / 'whole.mcap').read_bytes()
    cut = data.index(serialize_message(HasCommand(motor_speed=15.0)))  # inside the chunk
    (tmp_path / 'torn' / 'torn.mcap').write_bytes(data[:cut])
    assert bag_module.main(['info', str(tmp_path / 'torn')]) == 1
    assert 'never closed; if its recorder was killed' in capsys.readouterr().err
    out_dir = tmp_path / 'out'
    assert bag_module.main(['recover', str(tmp_path / 'torn'), '--output', str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert out.startswith('recovered ') and str(out_dir) in out
    with read_messages(out_dir) as messages:
        recovered = [m.data for m in messages]
    assert recovered == [serialize_message(HasCommand(motor_speed=float(i)))
                         for i in range(15)]
    assert not (tmp_path / 'torn' / 'metadata.yaml').exists()  # --output leaves the source be
    assert bag_module.main(['recover', str(tmp_path / 'torn'), '--output', str(out_dir)]) == 1
    assert 'exists already' in capsys.readouterr().err

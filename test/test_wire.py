"""Two standalone processes talk over DDS exactly as rmw_cyclonedds_cpp nodes would."""

import json
import math
import os
import time

from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsParticipant,
    BuiltinTopicDcpsPublication,
    BuiltinTopicDcpsSubscription,
)
from cyclonedds.domain import DomainParticipant
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from exo_has_runtime.standalone.context import LOOPBACK_CONFIG
from exo_has_runtime.standalone.messages import default_registry
from exo_has_runtime.testing.peers import fill_message
from exo_has_runtime.testing.processes import NodeProcess

PEERS = 'exo_has_runtime.testing.peers'
MESSAGES = {
    '/wire/has_command': ('exo_has_msgs/msg/HasCommand', {
        'header': {'stamp': {'sec': 3, 'nanosec': 5}}, 'joint': 'left_hip',
        'motor_speed': -418.879, 'enable': True}),
    '/wire/has_state': ('exo_has_msgs/msg/HasState', {
        'header': {'stamp': {'sec': 1_700_000_000, 'nanosec': 999_999_999}, 'frame_id': 'x'},
        'joint': 'right_knee', 'position': 0.029, 'velocity': -0.14, 'pressure_a': 1.75e7,
        'pressure_b': 0.0, 'motor_speed': 418.0, 'motor_speed_command': 420.0,
        'motor_current': math.nan, 'load_force': -490.5, 'valve_mode': 2}),
    '/wire/safety_event': ('exo_has_msgs/msg/SafetyEvent', {
        'joint': 'left_knee', 'kind': 1, 'severity': 3, 'value': 1.8e7, 'limit': 1.75e7,
        'latched': True, 'text': 'safety valve open: p_A 18.0 MPa \u2265 17.5 MPa'}),
    '/wire/joint_reference': ('sensor_msgs/msg/JointState', {
        'name': ['left_hip', 'left_knee', 'right_hip', 'right_knee'],
        'position': [0.1, -0.2, 0.3, -0.4], 'velocity': [1.0], 'effort': []}),
}


def expected_message(type_name, fields):
    return fill_message(default_registry().get_message(type_name)(), fields)


def test_every_exo_has_type_and_joint_state_cross_processes_with_rmw_conventions():
    os.environ.setdefault('CYCLONEDDS_URI', LOOPBACK_CONFIG)
    registry = default_registry()
    observer = DomainParticipant(int(os.environ['ROS_DOMAIN_ID']))
    participants = BuiltinDataReader(observer, BuiltinTopicDcpsParticipant)
    publications = BuiltinDataReader(observer, BuiltinTopicDcpsPublication)
    subscriptions = BuiltinDataReader(observer, BuiltinTopicDcpsSubscription)
    info_type = registry.get_message('rmw_dds_common/msg/ParticipantEntitiesInfo')
    discovery = DataReader(observer, Topic(observer, 'ros_discovery_info', info_type), qos=Qos(
        Policy.Reliability.Reliable(10**9), Policy.Durability.TransientLocal,
        Policy.History.KeepAll, Policy.DataRepresentation(use_cdrv0_representation=True)))

    record_specs = [f'{topic}={type_name}' for topic, (type_name, _) in MESSAGES.items()]
    publish_specs = [f'{topic}={type_name}={json.dumps(fields)}'
                     for topic, (type_name, fields) in MESSAGES.items()]
    with NodeProcess(PEERS, ['record', *record_specs, '--count', str(len(MESSAGES)),
                             '--duration', '20', '--name', 'wire_listener']) as recorder:
        recorder.wait_for_output('READY')
        with NodeProcess(PEERS, ['publish', *publish_specs, '--duration', '20',
                                 '--name', 'wire_talker', '--ros-args', '-r',
                                 '__ns:=/exo']) as talker:
            talker.wait_for_output('PUBLISHED')
            assert recorder.wait(timeout_s=20) == 0
            time.sleep(0.2)
            seen_participants = participants.take(N=100)
            seen_publications = publications.take(N=200)
            seen_subscriptions = subscriptions.take(N=200)
            infos = discovery.take(N=100)

    # Payload: rosbags' serialize_cdr of the same message, then rmw's padding to 4 bytes.
    lines = [json.loads(line) for line in recorder.output.splitlines() if line.startswith('{')]
    assert sorted(line['topic'] for line in lines) == sorted(MESSAGES)
    for line in lines:
        type_name, fields = MESSAGES[line['topic']]
        payload = bytes.fromhex(line['cdr'])
        message = expected_message(type_name, fields)
        reference = bytes(registry.typestore.serialize_cdr(registry.to_rosbags(message),
                                                           type_name))
        assert len(payload) % 4 == 0
        assert payload[:len(reference)] == reference, line['topic']
        assert set(payload[len(reference):]) <= {0}
        decoded = registry.typestore.deserialize_cdr(payload, type_name)
        if type_name.endswith('HasState'):
            assert math.isnan(decoded.motor_current) and decoded.valve_mode == 2
        if type_name.endswith('SafetyEvent'):
            assert decoded.text.endswith('\u2265 17.5 MPa')

    # Names and USER_DATA on the wire.
    by_topic = {p.topic_name: p for p in seen_publications if p.topic_name}
    for topic, (type_name, _) in MESSAGES.items():
        publication = by_topic[f'rt{topic}']
        package, _, name = type_name.split('/')
        assert publication.type_name == f'{package}::msg::dds_::{name}_'
        assert publication.qos[Policy.Userdata].data == \
            f'typehash={registry.type_hash(type_name)};'.encode()
        assert any(s.topic_name == f'rt{topic}' and s.type_name == publication.type_name
                   for s in seen_subscriptions)
    peers = [p for p in seen_participants
             if Policy.Userdata in p.qos and p.qos[Policy.Userdata].data == b'enclave=/;']
    assert len(peers) >= 2

    # ros_discovery_info lists each peer's node with the gids of its endpoints.
    nodes = {}
    for info in infos:
        for node in info.node_entities_info_seq:
            nodes[(node.node_namespace, node.node_name)] = (info, node)
    assert ('/exo', 'wire_talker') in nodes and ('/', 'wire_listener') in nodes
    talker_info, talker_node = nodes[('/exo', 'wire_talker')]
    writer_gids = {bytes(gid.data) for gid in talker_node.writer_gid_seq}
    for topic in MESSAGES:
        assert by_topic[f'rt{topic}'].key.bytes in writer_gids
    assert bytes(talker_info.gid.data) == by_topic['rt/wire/has_command'].participant_key.bytes

"""On the wire, our messages are the CDR every ROS 2 tool reads, and a plain DDS peer hears them.

rclpy's serializer (rmw_fastrtps_cpp's type support, built by rosidl from exo_has_msgs) is
checked against rosbags' independent one, for every exo_has_msgs type and for JointState; a
Cyclone DDS participant, with no ROS in it, then receives the HAS state of a running plant node,
as a robot running rmw_cyclonedds_cpp would.
"""

import importlib
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, uint8, uint32
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from exo_has_runtime.processes import NodeProcess

#: Every exo_has_msgs type and JointState, each field set, none to its default where avoidable.
MESSAGES = {
    'exo_has_msgs/msg/GaitPhase': {
        'header': {'stamp': {'sec': 1_764_000_004, 'nanosec': 7}, 'frame_id': ''},
        'motion': 1, 'phase': 0.625, 'amplitude': 0.5,
        'joints': ['left_hip', 'left_knee', 'right_hip', 'right_knee'],
        'moment_per_mass': [0.4, -0.25, -0.1, 0.9]},
    'exo_has_msgs/msg/HasCommand': {
        'header': {'stamp': {'sec': 1_764_000_003, 'nanosec': 5}, 'frame_id': ''},
        'joint': 'left_hip', 'motor_speed': -418.879, 'enable': True},
    'exo_has_msgs/msg/HasState': {
        'header': {'stamp': {'sec': 1_700_000_000, 'nanosec': 999_999_999}, 'frame_id': 'x'},
        'joint': 'right_knee', 'position': 0.029, 'velocity': -0.14, 'pressure_a': 1.75e7,
        'pressure_b': -3.5e4, 'motor_speed': 418.0, 'motor_speed_command': 420.0,
        'motor_current': math.nan, 'load_force': -490.5, 'valve_mode': 2},
    'exo_has_msgs/msg/SafetyEvent': {
        'header': {'stamp': {'sec': 12, 'nanosec': 345_678_901}, 'frame_id': 'base_link'},
        'joint': 'left_knee', 'kind': 1, 'severity': 3, 'value': 1.8e7, 'limit': 1.75e7,
        'latched': True, 'text': 'safety valve open: p_A 18.0 MPa \u2265 17.5 MPa', 'phase': 1},
    'sensor_msgs/msg/JointState': {
        'header': {'stamp': {'sec': 7, 'nanosec': 1}, 'frame_id': ''},
        'name': ['left_hip', 'left_knee', 'right_hip', 'right_knee'],
        'position': [0.1, -0.2, 0.3, -0.4], 'velocity': [1.0], 'effort': []},
}

#: Size and alignment of CDR's primitive types [bytes].
PRIMITIVE_SIZES = {'bool': 1, 'byte': 1, 'char': 1, 'int8': 1, 'uint8': 1, 'int16': 2,
                   'uint16': 2, 'int32': 4, 'uint32': 4, 'float32': 4, 'int64': 8,
                   'uint64': 8, 'float64': 8}

#: Encapsulation header in front of every serialized message: CDR, little endian, no options.
CDR_LE_HEADER = b'\x00\x01\x00\x00'


@pytest.fixture(scope='module')
def typestore():
    """Give rosbags' Jazzy types plus exo_has_msgs, parsed from the installed .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    msg_dir = Path(get_package_share_directory('exo_has_msgs')) / 'msg'
    types = {}
    for path in sorted(msg_dir.glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(encoding='utf-8'),
                                        f'exo_has_msgs/msg/{path.stem}'))
    assert sorted(types) == [f'exo_has_msgs/msg/{n}'
                             for n in ('GaitPhase', 'HasCommand', 'HasState', 'SafetyEvent')]
    store.register(types)
    return store


def rclpy_class(type_name):
    package, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


def build(typestore, type_name, fields, make):
    """Build a message of either library from nested field values."""
    values = {}
    for name, (kind, detail) in typestore.fielddefs[type_name][1]:
        value = fields[name]
        if kind == Nodetype.NAME:
            value = build(typestore, detail, value, make)
        values[name] = value
    return make(type_name, values)


def rclpy_message(typestore, type_name, fields):
    return build(typestore, type_name, fields,
                 lambda name, values: rclpy_class(name)(**values))


def rosbags_message(typestore, type_name, fields):
    def make(name, values):
        # rosbags holds sequences of numbers as numpy arrays.
        for field, (kind, detail) in typestore.fielddefs[name][1]:
            if kind == Nodetype.SEQUENCE and detail[0][1][0] in PRIMITIVE_SIZES:
                values[field] = np.asarray(values[field], dtype=np.dtype(detail[0][1][0]))
        return typestore.types[name](**values)
    return build(typestore, type_name, fields, make)


def plain(typestore, type_name, message):
    """Return a message of either library as nested dicts and lists, NaN as the string 'nan'."""
    def value_of(kind, detail, value):
        if kind == Nodetype.NAME:
            return plain(typestore, detail, value)
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            return [value_of(*detail[0], item) for item in value]
        value = value.item() if hasattr(value, 'item') else value
        return 'nan' if isinstance(value, float) and math.isnan(value) else value
    return {name: value_of(kind, detail, getattr(message, name))
            for name, (kind, detail) in typestore.fielddefs[type_name][1]}


def data_offsets(typestore, type_name, message):
    """Return the offsets, after the encapsulation header, of the bytes that carry data.

    The others are CDR's alignment padding, whose content CDR leaves unspecified.
    """
    offsets = []
    end = [0]

    def take(size, alignment):
        start = end[0] + -end[0] % alignment
        offsets.extend(range(start, start + size))
        end[0] = start + size

    def field(kind, detail, value):
        if kind == Nodetype.NAME:
            for name, (sub_kind, sub_detail) in typestore.fielddefs[detail][1]:
                field(sub_kind, sub_detail, getattr(value, name))
        elif kind == Nodetype.SEQUENCE:
            take(4, 4)
            for item in value:
                field(*detail[0], item)
        elif kind == Nodetype.ARRAY:
            for item in value:
                field(*detail[0], item)
        elif detail[0] == 'string':
            take(4, 4)
            take(len(value.encode('utf-8')) + 1, 1)
        else:
            size = PRIMITIVE_SIZES[detail[0]]
            take(size, size)

    field(Nodetype.NAME, type_name, message)
    return offsets


@pytest.mark.parametrize('type_name', sorted(MESSAGES))
def test_rclpy_serializes_every_message_type_to_the_bytes_rosbags_does(typestore, type_name):
    fields = MESSAGES[type_name]
    reference = bytes(typestore.serialize_cdr(rosbags_message(typestore, type_name, fields),
                                              type_name))
    data = bytes(serialize_message(rclpy_message(typestore, type_name, fields)))

    offsets = data_offsets(typestore, type_name, rosbags_message(typestore, type_name, fields))
    assert len(reference) == len(CDR_LE_HEADER) + offsets[-1] + 1
    padding = set(range(len(reference) - 4)) - set(offsets)
    assert padding, 'every type here has padding somewhere'
    assert all(reference[4 + i] == 0 for i in padding)
    assert data[:4] == reference[:4] == CDR_LE_HEADER
    # Byte for byte wherever there is data. Fast DDS leaves the padding bytes uninitialised
    # (they differ from one call to the next), and may add some past the end, which is why
    # this compares the data bytes only, and only as far as the reference goes.
    assert len(data) >= len(reference)
    assert bytes(data[4 + i] for i in offsets) == bytes(reference[4 + i] for i in offsets)


@pytest.mark.parametrize('type_name', sorted(MESSAGES))
def test_each_library_reads_the_others_bytes_back_to_the_same_fields(typestore, type_name):
    fields = MESSAGES[type_name]
    expected = plain(typestore, type_name, rclpy_message(typestore, type_name, fields))
    assert expected == plain(typestore, type_name,
                             rosbags_message(typestore, type_name, fields))
    reference = bytes(typestore.serialize_cdr(rosbags_message(typestore, type_name, fields),
                                              type_name))
    data = bytes(serialize_message(rclpy_message(typestore, type_name, fields)))

    from_rosbags = deserialize_message(reference, rclpy_class(type_name))
    assert plain(typestore, type_name, from_rosbags) == expected
    assert plain(typestore, type_name, deserialize_message(data, rclpy_class(type_name))) == \
        expected
    from_rclpy = typestore.deserialize_cdr(data[:len(reference)], type_name)
    assert plain(typestore, type_name, from_rclpy) == expected


def test_the_constants_of_every_exo_has_type_are_the_same_in_both_libraries(typestore):
    for type_name in MESSAGES:
        constants, _ = typestore.fielddefs[type_name]
        for name, _, value in constants:
            assert getattr(rclpy_class(type_name), name) == value, f'{type_name}.{name}'
    valve_modes = {name for name, _, _ in typestore.fielddefs['exo_has_msgs/msg/HasState'][0]}
    assert valve_modes == {'VALVE_FREE', 'VALVE_ASSIST', 'VALVE_RELIEF'}


def test_rclpy_serializes_an_empty_float64_sequence_past_the_data_which_rosbags_refuses(
        typestore):
    # rmw_fastrtps_cpp sizes serialize_message's buffer by its estimate, which aligns an empty
    # float64 sequence to 8 bytes; rosbags accepts at most 3 bytes past the data. So a bag
    # written from serialize_message (not from the bytes received, which are exact) can be
    # unreadable: its writers serialize with rosbags. This fails once Fast DDS is exact.
    fields = {'header': {'stamp': {'sec': 1, 'nanosec': 2}, 'frame_id': ''},
              'name': ['left_hip'], 'position': [0.3], 'velocity': [], 'effort': []}
    type_name = 'sensor_msgs/msg/JointState'
    reference = bytes(typestore.serialize_cdr(rosbags_message(typestore, type_name, fields),
                                              type_name))
    data = bytes(serialize_message(rclpy_message(typestore, type_name, fields)))
    assert len(data) > len(reference) + 3
    with pytest.raises(SerdeError, match='size mismatch'):
        typestore.deserialize_cdr(data, type_name)


# The CDR layout of HasState, for a DDS participant that has never heard of ROS: rmw names a
# type `package::msg::dds_::Name_` and a topic `rt/` + its ROS name.
@dataclass
class Time(IdlStruct, typename='builtin_interfaces::msg::dds_::Time_'):
    """builtin_interfaces/msg/Time."""

    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename='std_msgs::msg::dds_::Header_'):
    """std_msgs/msg/Header."""

    stamp: Time
    frame_id: str


@dataclass
class HasState(IdlStruct, typename='exo_has_msgs::msg::dds_::HasState_'):
    """exo_has_msgs/msg/HasState (its constants are not on the wire)."""

    header: Header
    joint: str
    position: float64
    velocity: float64
    pressure_a: float64
    pressure_b: float64
    motor_speed: float64
    motor_speed_command: float64
    motor_current: float64
    load_force: float64
    valve_mode: uint8


def test_the_dds_layout_above_has_the_fields_of_has_state_in_order(typestore):
    ours = [name for name, _ in typestore.fielddefs['exo_has_msgs/msg/HasState'][1]]
    assert list(HasState.__annotations__) == ours
    assert list(Header.__annotations__) == ['stamp', 'frame_id']


#: Cyclone DDS on loopback only, as the nodes are (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST):
#: loopback has no multicast here, so discovery is unicast to the well-known ports of
#: localhost's participants, which is where Fast DDS's localhost discovery looks as well.
CYCLONE_LOOPBACK = (
    '<CycloneDDS><Domain Id="any">'
    '<General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    '<AllowMulticast>false</AllowMulticast></General>'
    '<Discovery><ParticipantIndex>auto</ParticipantIndex>'
    '<Peers><Peer address="localhost"/></Peers></Discovery>'
    '</Domain></CycloneDDS>')


@pytest.mark.process
def test_a_plain_cyclone_dds_participant_receives_the_has_state_of_a_plant_node():
    domain_id = int(os.environ['ROS_DOMAIN_ID'])
    domain = Domain(domain_id, CYCLONE_LOOPBACK)
    participant = DomainParticipant(domain_id)
    reader = DataReader(participant, Topic(participant, 'rt/left_hip/has_state', HasState),
                        qos=Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(10)))
    with NodeProcess('exo_has_sim.plant_node',
                     ['--ros-args', '-p', 'joint:=left_hip']) as plant:
        # Starting includes compiling the model the first time: not part of what is measured.
        plant.wait_for_output('plant ready', timeout_s=60)
        deadline = time.monotonic() + 5.0
        samples = []
        while not samples and time.monotonic() < deadline:
            samples = reader.take(N=10)
            time.sleep(0.02)
        received_at = time.time()
    assert samples, f'no HasState reached Cyclone DDS within 5 s; plant output:\n{plant.output}'
    state = samples[-1]
    assert state.joint == 'left_hip' and state.header.frame_id == ''
    stamp = state.header.stamp.sec + state.header.stamp.nanosec * 1e-9
    assert abs(received_at - stamp) < 5.0  # the plant stamps with the system clock
    assert 0.0 <= state.position < 0.5  # within the cylinder's stroke [m]
    assert all(math.isfinite(value) for value in (
        state.velocity, state.pressure_a, state.pressure_b, state.motor_speed,
        state.motor_speed_command, state.load_force))
    assert math.isnan(state.motor_current)  # the plant does not model the current
    assert state.valve_mode in (0, 1, 2)
    del reader, participant, domain

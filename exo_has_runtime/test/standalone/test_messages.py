import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from exo_has_runtime.errors import MessageDefinitionError, UnknownMessageTypeError
from exo_has_runtime.standalone.messages import (
    MessageRegistry,
    dds_type_name,
    default_registry,
    get_message,
    ros_type_name,
)

WORKSPACE = Path(__file__).resolve().parents[3]


def populated(type_name):
    """Return a message of the type with a non-default value in every field."""
    registry = default_registry()
    message = registry.get_message(type_name)()
    for index, (name, ros_type) in enumerate(message.get_fields_and_field_types().items()):
        value = getattr(message, name)
        if ros_type.startswith(('float', 'double')):
            setattr(message, name, 1.5 * (index + 1))
        elif ros_type in ('uint8', 'int32', 'uint32', 'int8', 'byte'):
            setattr(message, name, index + 1)
        elif ros_type == 'bool':
            setattr(message, name, True)
        elif ros_type.startswith('string'):
            setattr(message, name, f'{name}-{index}')
        elif ros_type == 'sequence<string>':
            setattr(message, name, ['left_hip', 'right_knee'])
        elif ros_type == 'sequence<float64>':
            setattr(message, name, [0.1, -2.5, math.pi][: index % 3 + 1])
        elif hasattr(value, 'stamp'):
            value.stamp.sec, value.stamp.nanosec, value.frame_id = 17, 999, 'base_link'
        elif hasattr(value, 'nanosec'):
            value.sec, value.nanosec = 17, 999
    return message


@pytest.mark.parametrize('type_name', [
    'exo_has_msgs/msg/HasCommand', 'exo_has_msgs/msg/HasState', 'exo_has_msgs/msg/SafetyEvent',
    'sensor_msgs/msg/JointState', 'std_msgs/msg/Header',
])
def test_serialisation_is_byte_for_byte_rosbags_serialize_cdr_plus_rmw_padding(type_name):
    registry = default_registry()
    message = populated(type_name)
    ours = registry.serialize(message)
    reference = bytes(registry.typestore.serialize_cdr(registry.to_rosbags(message), type_name))
    assert ours[:4] == b'\x00\x01\x00\x00'  # CDR little endian, XCDR1
    assert len(ours) % 4 == 0
    assert ours[:len(reference)] == reference
    assert ours[len(reference):] == b'\0' * (len(ours) - len(reference))
    assert registry.deserialize(ours, type_name) == message


def test_a_diagnostic_array_round_trips_through_rosbags():
    registry = default_registry()
    array_type = get_message('diagnostic_msgs/msg/DiagnosticArray')
    status_type = get_message('diagnostic_msgs/msg/DiagnosticStatus')
    key_value = get_message('diagnostic_msgs/msg/KeyValue')
    message = array_type(status=[status_type(
        level=status_type.ERROR, name='watchdog', message='relief',
        values=[key_value(key='pressure_a', value='1.8e7')])])
    data = registry.serialize(message)
    decoded = registry.typestore.deserialize_cdr(data, 'diagnostic_msgs/msg/DiagnosticArray')
    assert decoded.status[0].values[0].value == '1.8e7'
    assert registry.from_rosbags(decoded, 'diagnostic_msgs/msg/DiagnosticArray') == message


def test_generated_classes_look_like_rosidl_classes():
    has_state = get_message('exo_has_msgs/msg/HasState')
    state = has_state(joint='left_knee', pressure_a=2.0e6)
    assert (has_state.VALVE_FREE, has_state.VALVE_ASSIST, has_state.VALVE_RELIEF) == (0, 1, 2)
    assert state.velocity == 0.0 and state.header.stamp.sec == 0
    assert has_state.get_fields_and_field_types()['header'] == 'std_msgs/Header'
    assert type(state).__module__ == 'exo_has_msgs.msg'
    assert get_message('exo_has_msgs/HasState') is has_state
    assert has_state().header is not has_state().header  # defaults are not shared


def test_dds_type_names_follow_rmw_cyclonedds():
    assert dds_type_name('exo_has_msgs/msg/HasCommand') == 'exo_has_msgs::msg::dds_::HasCommand_'
    assert get_message('exo_has_msgs/msg/HasCommand').__idl_typename__ == \
        'exo_has_msgs::msg::dds_::HasCommand_'
    assert ros_type_name('sensor_msgs::msg::dds_::JointState_') == 'sensor_msgs/msg/JointState'


def test_type_hashes_are_rihs01_and_match_the_rosbags_typestore():
    registry = default_registry()
    digest = registry.type_hash('sensor_msgs/msg/JointState')
    assert digest.startswith('RIHS01_') and len(digest) == 7 + 64
    assert digest == registry.typestore.hash_rihs01('sensor_msgs/msg/JointState')


@pytest.mark.parametrize(('name', 'message'), [
    ('exo_has_msgs/msg/Nope', "package 'exo_has_msgs' has no message of that name"),
    ('nope_msgs/msg/Thing', "unknown package 'nope_msgs'"),
    ('HasCommand', 'malformed message type name'),
])
def test_unknown_type_names_fail_with_a_clear_error(name, message):
    with pytest.raises(UnknownMessageTypeError, match=message):
        get_message(name)


def make_package(root, name, files):
    package = root / name
    (package / 'msg').mkdir(parents=True)
    (package / 'package.xml').write_text(f'<package format="3"><name>{name}</name></package>')
    for file_name, text in files.items():
        (package / 'msg' / file_name).write_text(text)
    return package


@pytest.mark.parametrize(('text', 'message'), [
    ('float64 x y z\n', r"Bad\.msg:1: default value 'y z' does not fit type float64"),
    ('int32[2] pair [1.5, 2]\n', r'Bad\.msg:1: default value .* does not fit type int32\[2\]'),
    ('float64 x\nfloat64 y z w\n', r'Bad\.msg:2: default value'),
    ('float64 position\nfloat64 Velocity\n', r'Bad\.msg:2: malformed line'),
    ('uint8 mode=\n', r'Bad\.msg:1: malformed line'),
    ('NoSuchType field\n', "field 'field' has unknown type 'bad_msgs/msg/NoSuchType'"),
    ('float64 has__double\n', r'Bad\.msg:1: malformed line'),
])
def test_malformed_msg_files_fail_naming_file_line_and_problem(tmp_path, text, message):
    make_package(tmp_path, 'bad_msgs', {'Bad.msg': text})
    with pytest.raises(MessageDefinitionError, match=message):
        MessageRegistry([tmp_path])


def test_msg_files_of_another_package_are_found_with_defaults_constants_and_nesting(tmp_path):
    make_package(tmp_path, 'extra_msgs', {
        'Gains.msg': '# PD gains\nfloat64 kp 35.0\nfloat64[2] limits [-1.0, 1.0]\n'
                     'string LABEL="pd # not a comment"\nexo_has_msgs/HasCommand command\n'})
    registry = MessageRegistry([tmp_path, WORKSPACE])
    gains = registry.get_message('extra_msgs/msg/Gains')()
    assert gains.kp == 35.0 and gains.limits == [-1.0, 1.0]
    assert registry.get_message('extra_msgs/msg/Gains').LABEL == 'pd # not a comment'
    data = registry.serialize(gains)
    reference = registry.typestore.serialize_cdr(
        registry.to_rosbags(gains), 'extra_msgs/msg/Gains')
    assert data[:len(reference)] == bytes(reference)


def test_the_workspace_msg_files_are_the_ones_found_by_default():
    assert default_registry().local_types == [
        'exo_has_msgs/msg/HasCommand', 'exo_has_msgs/msg/HasState',
        'exo_has_msgs/msg/SafetyEvent']


def test_rosbags_conversion_uses_numpy_arrays_for_numeric_sequences():
    joint_state = get_message('sensor_msgs/msg/JointState')(position=[1.0, 2.0])
    converted = default_registry().to_rosbags(joint_state)
    assert isinstance(converted.position, np.ndarray) and converted.position.dtype == np.float64


def test_a_copy_of_the_interface_package_elsewhere_is_found_through_the_environment(
        tmp_path, monkeypatch):
    shutil.copytree(WORKSPACE / 'exo_has_msgs', tmp_path / 'exo_has_msgs')
    (tmp_path / 'exo_has_msgs' / 'msg' / 'Extra.msg').write_text('float64 value\n')
    monkeypatch.setenv('EXO_HAS_INTERFACE_PATH', str(tmp_path))
    registry = MessageRegistry()
    assert 'exo_has_msgs/msg/Extra' in registry.local_types

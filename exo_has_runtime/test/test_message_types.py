import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from exo_has_common.errors import UnknownMessageTypeError
from exo_has_msgs.msg import HasState
from exo_has_runtime.errors import MalformedMessageError
from exo_has_runtime.message_types import deserialize, message_class


def test_a_message_class_is_found_by_its_full_or_short_type_name():
    assert message_class('exo_has_msgs/msg/HasState') is HasState
    assert message_class('sensor_msgs/JointState') is JointState


@pytest.mark.parametrize(('type_name', 'complaint'), [
    ('exo_has_msgs/msg/Nothing', r"'exo_has_msgs/msg/Nothing' is unknown here: exo_has_msgs"
                                 r'\.msg has no message Nothing'),
    ('no_such_msgs/msg/Pump', r"'no_such_msgs/msg/Pump' is unknown here: cannot import "
                              r'no_such_msgs\.msg'),
    ('exo_has_msgs/srv/HasState', "malformed message type name 'exo_has_msgs/srv/HasState'"),
    ('HasState', "malformed message type name 'HasState'"),
    ('exo_has_msgs/msg/__name__', r"'exo_has_msgs/msg/__name__' is unknown here"),
])
def test_an_unknown_or_malformed_type_name_is_named_in_the_error(type_name, complaint):
    with pytest.raises(UnknownMessageTypeError, match=complaint):
        message_class(type_name)


def test_bags_bytes_deserialize_as_rclpy_wrote_them_and_bad_bytes_are_named():
    # No efforts: rclpy's bytes that rosbags' deserialize_cdr refuses.
    joints = JointState(name=['left_hip', 'left_knee'], position=[0.1, 0.2], velocity=[1.0, 2.0])
    again = deserialize(serialize_message(joints), 'sensor_msgs/msg/JointState')
    assert list(again.position) == [0.1, 0.2] and list(again.effort) == []
    with pytest.raises(MalformedMessageError, match="5 bytes do not deserialize as 'exo_has_m"):
        deserialize(b'\x00\x01\x00\x00\x07', 'exo_has_msgs/msg/HasState')

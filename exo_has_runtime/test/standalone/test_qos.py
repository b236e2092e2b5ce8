import json

import pytest
from cyclonedds.qos import Policy

from exo_has_runtime.standalone.clock import Duration
from exo_has_runtime.standalone.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    dds_qos,
    qos_from_depth,
    qos_profile_sensor_data,
)
from exo_has_runtime.testing.processes import NodeProcess

PEERS = 'exo_has_runtime.testing.peers'
COMMAND = 'exo_has_msgs/msg/HasCommand'


def test_ros_profiles_map_to_the_dds_policies_rmw_cyclonedds_sets():
    qos = dds_qos(QoSProfile(depth=0, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             deadline=Duration(seconds=0.01)), b'typehash=RIHS01_00;')
    assert qos[Policy.History] == Policy.History.KeepLast(1)
    assert qos[Policy.Reliability] == Policy.Reliability.Reliable(0x7FFFFFFFFFFFFFFF)
    assert qos[Policy.Durability] == Policy.Durability.TransientLocal
    assert qos[Policy.DurabilityService].history == Policy.History.KeepLast(1)
    assert qos[Policy.Deadline] == Policy.Deadline(10_000_000)
    assert qos[Policy.WriterDataLifecycle] == Policy.WriterDataLifecycle(autodispose=False)
    assert qos[Policy.DataRepresentation] == Policy.DataRepresentation(
        use_cdrv0_representation=True)
    assert qos[Policy.Userdata] == Policy.Userdata(b'typehash=RIHS01_00;')
    assert Policy.Lifespan not in qos
    sensor = dds_qos(qos_profile_sensor_data)
    assert sensor[Policy.Reliability] == Policy.Reliability.BestEffort
    assert sensor[Policy.History] == Policy.History.KeepLast(5)
    assert dds_qos(QoSProfile(history=HistoryPolicy.KEEP_ALL))[Policy.History] == \
        Policy.History.KeepAll


def test_a_depth_stands_for_a_reliable_volatile_keep_last_profile():
    assert qos_from_depth(7) == QoSProfile(depth=7)
    with pytest.raises(TypeError, match='QoSProfile or a history depth'):
        qos_from_depth('10')
    with pytest.raises(ValueError, match='not supported'):
        QoSProfile(reliability=ReliabilityPolicy.BEST_AVAILABLE)


def received(recorder):
    return [json.loads(line) for line in recorder.output.splitlines() if line.startswith('{')]


def test_a_late_joining_subscriber_gets_the_transient_local_message():
    qos = 'reliable,transient_local,1'
    with NodeProcess(PEERS, ['publish', f'/latched={COMMAND}={{"joint": "left_hip"}}',
                             '--qos', qos, '--no-wait', '--duration', '20']) as publisher:
        publisher.wait_for_output('PUBLISHED')
        with NodeProcess(PEERS, ['record', f'/latched={COMMAND}', '--qos', qos,
                                 '--count', '1', '--duration', '15']) as late:
            assert late.wait(timeout_s=20) == 0
            assert len(received(late)) == 1


def test_a_volatile_late_joiner_gets_nothing_old():
    with NodeProcess(PEERS, ['publish', f'/volatile={COMMAND}={{}}', '--no-wait',
                             '--duration', '20']) as publisher:
        publisher.wait_for_output('PUBLISHED')
        with NodeProcess(PEERS, ['record', f'/volatile={COMMAND}', '--count', '1',
                                 '--duration', '2']) as late:
            late.wait(timeout_s=10)
            assert received(late) == []


@pytest.mark.parametrize(('publisher_qos', 'subscriber_qos', 'delivered'), [
    ('reliable,volatile,10', 'best_effort,volatile,10', True),
    ('best_effort,volatile,10', 'reliable,volatile,10', False),
])
def test_reliability_matches_as_in_ros2(publisher_qos, subscriber_qos, delivered):
    with NodeProcess(PEERS, ['record', f'/rel={COMMAND}', '--qos', subscriber_qos,
                             '--count', '1', '--duration', '6']) as recorder:
        recorder.wait_for_output('READY')
        with NodeProcess(PEERS, ['publish', f'/rel={COMMAND}={{"motor_speed": 3.0}}', '--qos',
                                 publisher_qos, '--no-wait', '--period', '0.05',
                                 '--duration', '8']):
            recorder.wait(timeout_s=15)
    assert bool(received(recorder)) is delivered

import math
from datetime import datetime
from pathlib import Path

import pytest
from rclpy.duration import Duration, Infinite
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from exo_has_common.bag import BagWriter, bag_topics, offered_qos
from exo_has_runtime.errors import ReplayError
from exo_has_runtime.recording import (
    DEFAULT_REPLAY_DEPTH,
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

T0_NS = 1_700_000_000_000_000_000


def recorded(reliability, durability, depth, history=QosHistory.KEEP_LAST):
    return Qos(history, depth, reliability, durability, QosTime(0, 0), QosTime(0, 0),
               QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


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
    # A publisher joining later with less: the subscription is made weaker, never stronger.
    current = QosChoice(True, True, RECORD_DEPTH)
    assert weakened_qos(current, [latched]) is None and weakened_qos(current, []) is None
    assert weakened_qos(current, [latched, reliable]) == QosChoice(True, False, RECORD_DEPTH)
    assert weakened_qos(current, [best_effort]) == QosChoice(False, False, RECORD_DEPTH)
    assert weakened_qos(QosChoice(False, False, RECORD_DEPTH), [latched]) is None


def test_replay_offers_what_was_recorded_and_a_usable_depth_where_none_was_told():
    reliable = recorded(QosReliability.RELIABLE, QosDurability.VOLATILE, 7)
    latched = recorded(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, 3)
    assert replay_qos([]) == QosChoice(True, False, DEFAULT_REPLAY_DEPTH)
    assert replay_qos([reliable, latched]) == QosChoice(True, False, 7)
    assert replay_qos([latched]) == QosChoice(True, True, 3)
    best_effort = recorded(QosReliability.BEST_EFFORT, QosDurability.VOLATILE, 1)
    assert replay_qos([reliable, best_effort]) == QosChoice(False, False, 7)
    # What rmw_fastrtps_cpp reports of a publisher: history unknown, depth 0.
    unknown = recorded(QosReliability.RELIABLE, QosDurability.VOLATILE, 0, QosHistory.UNKNOWN)
    assert replay_qos([unknown]) == QosChoice(True, False, DEFAULT_REPLAY_DEPTH)


def test_an_offered_profile_is_recorded_with_every_policy_and_duration(tmp_path):
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=7,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         deadline=Duration(seconds=1, nanoseconds=5),
                         liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
                         liveliness_lease_duration=Infinite)
    qos = offered_qos(profile)
    assert qos == Qos(QosHistory.KEEP_LAST, 7, QosReliability.BEST_EFFORT,
                      QosDurability.TRANSIENT_LOCAL, QosTime(1, 5), QosTime(0, 0),
                      QosLiveliness.MANUAL_BY_TOPIC, QosTime(9223372036, 854775807), False)
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/a', 'std_msgs/msg/Empty', [qos])
    assert bag_topics(tmp_path / 'bag')[0].offered_qos == (qos,)


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
    with BagWriter(tmp_path / 'bag') as writer:
        writer.add_topic('/a', 'std_msgs/msg/Empty')
    for argv, complaint in [([str(tmp_path / 'none')], 'no bag at'),
                            ([str(tmp_path / 'bag'), '--rate', '0'], 'positive factor'),
                            ([str(tmp_path / 'bag'), '--topics', '/x'], 'no topic /x'),
                            ([str(tmp_path / 'bag'), '--delay', '-1'], 'delay must be')]:
        assert replay_main(argv) == 1
        assert complaint in capsys.readouterr().err

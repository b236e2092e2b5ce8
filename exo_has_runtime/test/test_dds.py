"""The DDS transport every exo_has process takes: UDP, never Fast DDS's shared memory."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import has_command_topic
from exo_has_runtime.dds import (
    ANNOUNCEMENT_PERIOD,
    RMW_LOCALHOST_ENVIRONMENT,
    announcement_period,
    configure_transport,
    discovery_range,
    is_localhost_profile,
    localhost_profile,
    static_peers,
    write_profile,
)
from exo_has_runtime.errors import DdsConfigurationError
from exo_has_runtime.processes import NodeProcess

NAMESPACE = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def configured(**environ: str) -> tuple[dict[str, str], str]:
    env = dict(environ)
    warning = configure_transport(env)
    return env, warning


def profile_peers(path: str) -> list[str]:
    root = ET.parse(path).getroot()
    return [a.text or '' for a in root.findall('.//p:initialPeersList//p:address', NAMESPACE)]


def test_subnet_and_an_unset_range_take_udp_alone():
    for environ in ({}, {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'},
                    {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'system_default'}):
        env, warning = configured(**environ)
        assert env == {**environ, 'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}
        assert warning == ''


def test_a_users_builtin_transports_are_kept_and_shared_memory_among_them_is_warned_of():
    env, warning = configured(FASTDDS_BUILTIN_TRANSPORTS='UDPv6')
    assert env == {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv6'} and warning == ''
    env, warning = configured(FASTDDS_BUILTIN_TRANSPORTS='DEFAULT')
    assert env == {'FASTDDS_BUILTIN_TRANSPORTS': 'DEFAULT'}
    assert 'FASTDDS_BUILTIN_TRANSPORTS=DEFAULT' in warning and '0.33 s' in warning


def test_localhost_becomes_a_udp_profile_that_finds_peers_on_this_machine_and_static_ones():
    env, warning = configured(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                              ROS_STATIC_PEERS='192.168.1.20; localhost')
    assert warning == ''
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert 'FASTDDS_BUILTIN_TRANSPORTS' not in env
    path = env['FASTRTPS_DEFAULT_PROFILES_FILE']
    assert is_localhost_profile(path)
    assert profile_peers(path) == ['127.0.0.1', '192.168.1.20', '127.0.0.1']
    root = ET.parse(path).getroot()
    assert root.find('.//p:useBuiltinTransports', NAMESPACE).text == 'false'
    assert root.find('.//p:transport_descriptor/p:type', NAMESPACE).text == 'UDPv4'
    # Announcements every 0.5 s, not Fast DDS's 3 s: a join that misses its first exchange
    # waits for the next one (bench/discovery.py).
    announcement = root.find('.//p:builtin/p:discovery_config/p:leaseAnnouncement', NAMESPACE)
    assert (announcement.find('p:sec', NAMESPACE).text,
            announcement.find('p:nanosec', NAMESPACE).text) == ('0', '500000000')


def test_the_deprecated_localhost_only_is_taken_as_localhost_and_dropped():
    env, _ = configured(ROS_LOCALHOST_ONLY='1')
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert 'ROS_LOCALHOST_ONLY' not in env
    assert discovery_range({'ROS_LOCALHOST_ONLY': '0'}) == 'SUBNET'
    assert discovery_range({'ROS_LOCALHOST_ONLY': '1',
                            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'subnet'}) == 'SUBNET'


def test_configuring_twice_changes_nothing_more():
    for environ in ({}, {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}):
        once, _ = configured(**environ)
        twice = dict(once)
        configure_transport(twice)
        assert twice == once


def test_a_child_given_a_range_of_its_own_drops_the_inherited_localhost_profile():
    parent, _ = configured(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    child = {**parent, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
             'ROS_STATIC_PEERS': '10.77.0.2'}
    configure_transport(child)
    assert 'FASTRTPS_DEFAULT_PROFILES_FILE' not in child
    assert child['FASTDDS_BUILTIN_TRANSPORTS'] == 'UDPv4'


def test_a_users_profiles_file_is_theirs_and_with_localhost_it_is_warned_of():
    env, warning = configured(FASTRTPS_DEFAULT_PROFILES_FILE='/etc/mine.xml')
    assert env == {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'} and warning == ''
    env, warning = configured(FASTRTPS_DEFAULT_PROFILES_FILE='/etc/mine.xml',
                              ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert '/etc/mine.xml' in warning and 'shared memory' in warning


def test_another_rmw_discovery_off_and_the_rmw_choice_are_left_as_they_are():
    for environ in ({'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'},
                    {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'},
                    {'EXO_HAS_DDS_TRANSPORT': 'rmw',
                     'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}):
        env, warning = configured(**environ)
        assert env == environ and warning == ''


def test_an_unknown_transport_choice_or_peer_is_refused_by_name():
    with pytest.raises(DdsConfigurationError, match="EXO_HAS_DDS_TRANSPORT='shm'"):
        configured(EXO_HAS_DDS_TRANSPORT='shm')
    with pytest.raises(DdsConfigurationError, match=r"'no-such-host\.invalid'"):
        static_peers('10.0.0.1;no-such-host.invalid')


def test_the_dynamic_fast_dds_rmw_is_configured_too_and_an_unwritable_profile_is_named(
        tmp_path, monkeypatch):
    env, _ = configured(RMW_IMPLEMENTATION='rmw_fastrtps_dynamic_cpp')
    assert env['FASTDDS_BUILTIN_TRANSPORTS'] == 'UDPv4'
    monkeypatch.setattr('tempfile.tempdir', str(tmp_path / 'missing'))
    with pytest.raises(DdsConfigurationError, match='cannot write the Fast DDS profile'):
        configured(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


def test_a_profile_is_written_once_under_a_name_of_its_content(tmp_path):
    text = localhost_profile(['10.0.0.2'])
    first = write_profile(text, tmp_path)
    assert write_profile(text, tmp_path) == first
    assert first.read_text() == text
    assert write_profile(localhost_profile(), tmp_path) != first
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [first.name, write_profile(localhost_profile(), tmp_path).name])


def shared_memory_mapped_by(script: str, env: dict[str, str]) -> int:
    """Run a Python script that creates a participant; count its Fast DDS shared-memory maps."""
    probe = textwrap.dedent("""
        import sys
        from pathlib import Path
        SCRIPT
        maps = Path('/proc/self/maps').read_text()
        print(sum('/dev/shm/fastrtps_' in line for line in maps.splitlines()))
    """).replace('SCRIPT', textwrap.dedent(script).strip())
    result = subprocess.run([sys.executable, '-c', probe], env={**os.environ, **env},
                            capture_output=True, text=True, timeout=60, check=True)
    return int(result.stdout.strip().splitlines()[-1])


@pytest.mark.process
def test_rmw_fastrtps_still_adds_shared_memory_under_localhost_even_asked_for_udp():
    # The defect this module works around: if this fails, rmw_fastrtps_cpp no longer forces
    # shared memory under LOCALHOST and exo_has_runtime.dds can be simplified.
    plain = {**RMW_LOCALHOST_ENVIRONMENT, 'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}
    script = """
        import rclpy
        rclpy.init()
        node = rclpy.create_node('plain_participant')
    """
    assert shared_memory_mapped_by(script, plain) > 0


@pytest.mark.process
def test_an_exo_has_process_maps_no_shared_memory_under_localhost_or_subnet():
    script = """
        from exo_has_runtime.dds import configure_transport
        configure_transport()
        import rclpy
        rclpy.init()
        node = rclpy.create_node('exo_has_participant')
    """
    for discovery in ('LOCALHOST', 'SUBNET'):
        env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': discovery, 'FASTRTPS_DEFAULT_PROFILES_FILE': '',
               'FASTDDS_BUILTIN_TRANSPORTS': ''}
        assert shared_memory_mapped_by(script, env) == 0, discovery


@pytest.mark.process
def test_nodes_on_udp_find_each_other_under_localhost(tmp_path: Path):
    # The test process runs under LOCALHOST, configured by conftest.py as every node is.
    with NodeProcess('exo_has_runtime.examples.command_talker', ('--ros-args', '-p', 'rate:=50.0'),
                     log_path=tmp_path / 'talker.log') as talker, \
            NodeProcess('exo_has_runtime.topic_tool', (
                'record', *(f'{has_command_topic(j)}=exo_has_msgs/msg/HasCommand'
                            for j in JOINT_NAMES),
                '--count', '20', '--duration', '20', '--qos', 'best_effort,volatile,10'),
                log_path=tmp_path / 'peer.log') as peer:
        # The talker sends once every command topic has a reader: the peer's four.
        assert peer.wait(30.0) == 0, peer.output
        assert peer.output.count('"topic"') == 20, peer.output
        assert talker.process.poll() is None
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'


def test_a_profile_asked_for_another_announcement_period_carries_it_in_seconds_and_ns():
    root = ET.fromstring(localhost_profile(announcement_period=0.5))
    announcement = root.find('.//p:builtin/p:discovery_config/p:leaseAnnouncement', NAMESPACE)
    assert (announcement.find('p:sec', NAMESPACE).text,
            announcement.find('p:nanosec', NAMESPACE).text) == ('0', '500000000')
    root = ET.fromstring(localhost_profile(announcement_period=3.0))
    announcement = root.find('.//p:builtin/p:discovery_config/p:leaseAnnouncement', NAMESPACE)
    assert announcement.find('p:sec', NAMESPACE).text == '3'
    root = ET.fromstring(localhost_profile(announcement_period=None))
    assert root.find('.//p:builtin/p:discovery_config', NAMESPACE) is None  # Fast DDS's own


def test_the_announcement_period_is_read_from_the_profile_in_use_else_fast_dds_own(tmp_path):
    env, _ = configured(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    assert announcement_period(env) == ANNOUNCEMENT_PERIOD == 0.5
    assert announcement_period({}) == 3.0  # SUBNET: no profile, Fast DDS's own
    own = tmp_path / 'own.xml'
    for text, period in [(localhost_profile(announcement_period=1.25), 1.25),
                         (localhost_profile(announcement_period=None), 3.0),
                         ('<profiles><unclosed', 3.0)]:
        own.write_text(text)
        assert announcement_period({'FASTRTPS_DEFAULT_PROFILES_FILE': str(own)}) == period
    assert announcement_period({'FASTRTPS_DEFAULT_PROFILES_FILE': str(tmp_path / 'gone')}) == 3.0

import time
import xml.etree.ElementTree as ET

from exo_has_runtime.cli import main, subcommands
from exo_has_runtime.dds_config import LOOPBACK_CONFIG
from exo_has_runtime.testing.processes import NodeProcess


def test_subcommands_are_gathered_from_the_installed_packages():
    assert {'demo', 'dds-config'} <= set(subcommands())


def test_an_unknown_subcommand_is_named_with_the_known_ones(capsys):
    assert main(['frobnicate']) == 2
    err = capsys.readouterr().err
    assert "unknown subcommand 'frobnicate'" in err and 'demo' in err


def test_help_lists_the_subcommands(capsys):
    assert main(['--help']) == 0
    assert 'dds-config' in capsys.readouterr().out


def test_the_printed_dds_config_is_the_loopback_configuration(capsys):
    assert main(['dds-config']) == 0
    printed = capsys.readouterr().out.strip()
    assert printed == LOOPBACK_CONFIG
    domain = ET.fromstring(printed).find('Domain')
    assert domain.find('General/AllowMulticast').text == 'false'
    assert domain.find('General/Interfaces/NetworkInterface').get('address') == '127.0.0.1'
    assert domain.find('Discovery/Peers/Peer').get('address') == 'localhost'


def test_the_demonstration_nodes_exchange_commands_and_states_for_every_joint():
    with NodeProcess('exo_has_runtime.demo.state_echo'):
        time.sleep(1.0)  # let the echo subscribe first
        talker = NodeProcess('exo_has_runtime.demo.command_talker',
                             ['--ros-args', '-p', 'duration:=2.5'])
        assert talker.wait(timeout_s=60) == 0, talker.output
    output = talker.output
    reports = [line for line in output.splitlines() if 'states received' in line]
    assert reports, output
    sent = int(reports[-1].split('commands sent ')[1].split(',')[0])
    received = int(reports[-1].split('states received ')[1].split(';')[0])
    assert sent >= 4 * 200 * 2 * 0.9  # four joints at 200 Hz for (nearly) 2.5 s
    assert received >= 0.95 * sent

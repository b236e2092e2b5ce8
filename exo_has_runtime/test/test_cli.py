import importlib
import time
from importlib.metadata import entry_points

import pytest

from exo_has_runtime.cli import main, subcommands
from exo_has_runtime.processes import NodeProcess

# Subcommands this workspace's packages register in their setup.py.
REGISTERED = {'bag', 'demo', 'design-check', 'diagnose', 'replay'}


def test_subcommands_are_gathered_from_the_installed_packages():
    assert set(subcommands()) == REGISTERED


def test_every_registered_subcommand_names_an_importable_function():
    # The entry points are read from the build's metadata: a subcommand whose module was
    # removed or renamed stays listed until the next build, and fails only when run.
    for name in sorted(subcommands()):
        (entry_point,) = entry_points(group='exo_has.commands', name=name)
        module_name, _, function_name = entry_point.value.partition(':')
        module = importlib.import_module(module_name)
        assert callable(getattr(module, function_name)), entry_point.value


def test_an_unknown_subcommand_is_named_with_the_known_ones(capsys):
    assert main(['frobnicate']) == 2
    err = capsys.readouterr().err
    assert "unknown subcommand 'frobnicate'" in err and 'demo' in err


def test_help_lists_the_subcommands(capsys):
    assert main(['--help']) == 0
    assert f'subcommands: {", ".join(sorted(REGISTERED))}' in capsys.readouterr().out


@pytest.mark.process
def test_the_demonstration_nodes_exchange_commands_and_states_for_every_joint():
    with NodeProcess('exo_has_runtime.examples.state_echo'):
        time.sleep(1.0)  # let the echo subscribe first
        with NodeProcess('exo_has_runtime.examples.command_talker',
                         ['--ros-args', '-p', 'duration:=2.5']) as talker:
            assert talker.wait(timeout_s=60) == 0, talker.output
    output = talker.output
    reports = [line for line in output.splitlines() if 'states received' in line]
    assert reports, output
    sent = int(reports[-1].split('commands sent ')[1].split(',')[0])
    received = int(reports[-1].split('states received ')[1].split(';')[0])
    assert sent >= 4 * 200 * 2 * 0.9  # four joints at 200 Hz for (nearly) 2.5 s
    assert received >= 0.95 * sent

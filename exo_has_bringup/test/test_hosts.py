"""Virtual hosts: refused clearly without root, and nothing left behind when the runner dies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from exo_has_bringup import hosts
from exo_has_bringup.errors import HostsUnavailableError
from exo_has_bringup.hosts import check_privileges
from exo_has_runtime.processes import tethered

RUNNER = """
import time
from exo_has_bringup.hosts import VirtualHosts
virtual = VirtualHosts()
virtual.start()
virtual.set_loss(0.1)
print(' '.join(h.netns for h in virtual.hosts.values()), flush=True)
time.sleep(60)
"""


def test_without_root_two_hosts_are_refused_naming_what_is_needed(monkeypatch):
    monkeypatch.setattr(os, 'geteuid', lambda: 1000)
    with pytest.raises(HostsUnavailableError, match=r'need root .* run as root, or with sudo'):
        check_privileges()


def test_a_missing_tool_is_named_with_its_package(monkeypatch):
    monkeypatch.setattr(os, 'geteuid', lambda: 0)
    monkeypatch.setattr(hosts.shutil, 'which', lambda tool: None if tool == 'iptables' else tool)
    check_privileges()  # losses not asked for: iptables not needed
    with pytest.raises(HostsUnavailableError, match='need iptables: install iptables'):
        check_privileges(losses=True)


@pytest.mark.process
def test_a_runner_killed_by_sigkill_leaves_no_namespace_link_or_holder_behind(
        virtual_hosts_available):
    before = {p.name for p in Path('/sys/class/net').iterdir()}
    runner = subprocess.Popen(tethered([sys.executable, '-c', RUNNER]), stdout=subprocess.PIPE,
                              text=True, cwd='/tmp')
    try:
        namespaces = runner.stdout.readline().split()
        assert len(namespaces) == 2, namespaces
        holders = [int(ns.split('/')[2]) for ns in namespaces]
        # While it runs, the link exists only inside the namespaces, not here.
        assert {p.name for p in Path('/sys/class/net').iterdir()} == before
    finally:
        runner.send_signal(signal.SIGKILL)
        runner.wait()
    deadline = time.monotonic() + 5.0
    while any(Path(f'/proc/{pid}').exists() for pid in holders) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in holders if Path(f'/proc/{pid}').exists()]
    assert {p.name for p in Path('/sys/class/net').iterdir()} == before

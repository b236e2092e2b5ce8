"""Session-wide test set-up: every test run on a ROS domain of its own, this machine only."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator

import pytest

from exo_has_runtime.dds import configure_transport

# Before any participant exists: child processes inherit both, so a test run never meets the
# nodes of another run (or of a demo) on this machine, nor anything on the network.
os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(100, 200))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)
# The transport every exo_has process takes (UDP: exo_has_runtime.dds), here for the test process's
# own participants and the processes it starts.
configure_transport()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark unit every test that starts no process and runs quickly (the quick run, -m unit)."""
    for item in items:
        if item.get_closest_marker('process') is None and item.get_closest_marker('slow') is None:
            item.add_marker(pytest.mark.unit)


@pytest.fixture
def ros_context() -> Iterator[object]:
    """Give a fresh, initialised rclpy context, shut down after the test."""
    from rclpy.context import Context

    context = Context()
    context.init(['test'])
    yield context
    context.try_shutdown()


@pytest.fixture(scope='session')
def virtual_hosts_available() -> None:
    """Skip a test that needs two virtual hosts where they cannot be made, saying why.

    In CI (``CI`` set), which runs as root with the tools installed, fail instead: there the
    two-host tests must run.
    """
    from exo_has_bringup.errors import HostsUnavailableError
    from exo_has_bringup.hosts import check_privileges

    try:
        check_privileges(losses=True)
    except HostsUnavailableError as exc:
        if os.environ.get('CI'):
            raise
        pytest.skip(str(exc))

"""Session-wide test set-up: every test run on a ROS domain of its own, this machine only."""

from __future__ import annotations

import contextlib
import os
import random
import signal
from collections.abc import Iterator
from typing import Any

import pytest

from exo_has_runtime.dds import configure_transport
from exo_has_runtime.processes import children

# Before any participant exists: child processes inherit both, so a test run never meets the
# nodes of another run (or of a demo) on this machine, nor anything on the network. A
# pytest-xdist worker (gw0, gw1, ...) inherits its run's domain and takes the next ones, so
# that the workers of one run do not meet either.
_worker = os.environ.get('PYTEST_XDIST_WORKER', '')
if _worker.startswith('gw') and os.environ.get('ROS_DOMAIN_ID', '').isdigit():
    os.environ['ROS_DOMAIN_ID'] = str(int(os.environ['ROS_DOMAIN_ID']) + 1 + int(_worker[2:]))
else:
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


@pytest.fixture(autouse=True, scope='module')
def no_process_left_behind(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail a module whose tests leave a process of theirs running, and end those processes.

    A process a failed test left running (started outside a ``with``) went on publishing into
    the next modules' graphs, and they failed with it ("a second source of the joint's state").
    Checked when the module's fixtures have ended; multiprocessing's own helper is not a test's.
    """
    yield
    left = {pid: command for pid, command in children().items()
            if 'multiprocessing.resource_tracker' not in command}
    for pid in left:
        try:
            os.killpg(pid, signal.SIGKILL)  # its own session: NodeProcess, Processes
        except OSError:
            with contextlib.suppress(OSError):  # ended meanwhile
                os.kill(pid, signal.SIGKILL)
    if left:
        pytest.fail(f'{request.module.__name__} left {len(left)} process(es) running, now '
                    f'killed: ' + '; '.join(f'{pid}: {cmd[:200]}' for pid, cmd in left.items()))


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


@pytest.fixture(scope='module')
def diagnoses(request: pytest.FixtureRequest,
              tmp_path_factory: pytest.TempPathFactory) -> Any:
    """Run the diagnoses an acceptance module queues in a pool of a process per core.

    The module queues its own (``queue_diagnoses(pool, folder)``), and gets its
    ``diagnosis_runs.Queued`` with every diagnosis ended. ``./run test`` runs these modules on
    pytest-xdist workers beside the quick tests (``--dist loadfile``: a module's tests on one
    worker, so its pool is made once), which take a core wherever a module's last diagnoses
    leave one idle.
    """
    from diagnosis_runs import diagnosis_pool  # test/ is on the path once its modules are

    module = request.module
    with diagnosis_pool() as pool:
        queued = module.queue_diagnoses(pool, tmp_path_factory.mktemp(module.__name__))
        queued.wait()
    return queued

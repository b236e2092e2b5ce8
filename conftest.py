"""Session-wide test set-up: every test run on a ROS domain of its own, this machine only."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from typing import Any

import pytest

from exo_has_runtime.dds import configure_transport

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


#: The acceptance modules of the diagnosis that queue their diagnoses in one pool, in the order
#: they queue them: the longest diagnoses first (a position-only record of the third plant,
#: the position-only dead zone and relief valve), the first plant's short draws last.
DIAGNOSIS_MODULES = ('test_third_truth_plant_diagnosis', 'test_hidden_effects_position_only',
                     'test_detection_limits', 'test_hidden_effects')


@pytest.fixture(scope='session')
def diagnoses(request: pytest.FixtureRequest,
              tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Run the diagnoses of the acceptance modules collected in one pool; each module's by name.

    Each module queues its own (``queue_diagnoses(pool, folder)``, giving its
    ``diagnosis_runs.Queued``). With a pool per module, one core idled while the other ended
    each module's last diagnosis, and test_detection_limits.py diagnosed its first record
    alone before its pool started; here both run beside the other modules' diagnoses. All have
    ended on return, before any process test starts.
    """
    from diagnosis_runs import diagnosis_pool  # test/ is on the path once its modules are

    modules = {item.module.__name__: item.module for item in request.session.items
               if hasattr(getattr(item, 'module', None), 'queue_diagnoses')}
    order = sorted(modules, key=lambda name: DIAGNOSIS_MODULES.index(name)
                   if name in DIAGNOSIS_MODULES else len(DIAGNOSIS_MODULES))
    queued = {}
    with diagnosis_pool() as pool:
        for name in order:
            queued[name] = modules[name].queue_diagnoses(pool, tmp_path_factory.mktemp(name))
        for each in queued.values():
            each.wait()
    return queued

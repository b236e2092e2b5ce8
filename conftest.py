"""Session-wide test set-up: every test run on a DDS domain of its own, loopback only."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator

import pytest

# Before any participant exists: child processes inherit both, so a test run never meets the
# nodes of another run (or of a demo) on this machine.
os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(100, 200))
os.environ.pop('CYCLONEDDS_URI', None)
os.environ['EXO_HAS_BACKEND'] = 'standalone'


@pytest.fixture
def ros_context() -> Iterator[object]:
    """Give a fresh, initialised standalone context, shut down after the test."""
    from exo_has_runtime.standalone import Context

    context = Context()
    context.init(['test'])
    yield context
    context.try_shutdown()

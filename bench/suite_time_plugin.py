"""The pytest plugin of bench/suite_time.py: each module's CPU, each run's wall and busy cores.

Loaded by ``-p suite_time_plugin`` (bench/ on ``PYTHONPATH``) in a pytest run and in each of its
pytest-xdist workers, it appends JSON lines to the file that ``SUITE_TIME_OUT`` names, and does
nothing where that is unset:

- per test module, on the process that ran it: the CPU seconds of its tests, their fixtures
  and their teardown, the process's own (``self``) and its reaped child processes' (``children``:
  a diagnosis pool, the nodes of a session), the wall seconds, the tests;
- per run, on the process that started it (the controller where xdist runs workers): the marker
  expression, the wall seconds from the session's start to its end, the machine's busy cores
  over them (``common.machine_ticks``: user, nice, system, irq and softirq time; steal apart)
  and the exit status.

Lines are appended whole (``O_APPEND``), so that the workers of one run may share the file.
"""

from __future__ import annotations

import json
import os
import resource
import time
from typing import Any

import pytest
from common import machine_ticks

#: The variable naming the file of records; without it the plugin records nothing.
OUT_VARIABLE = 'SUITE_TIME_OUT'

_module: dict[str, Any] = {}
_run: dict[str, Any] = {}


def cpu_seconds() -> tuple[float, float]:
    """Return this process's CPU seconds and its reaped children's (user and system)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    reaped = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, reaped.ru_utime + reaped.ru_stime


def _append(record: dict[str, Any]) -> None:
    line = (json.dumps(record) + '\n').encode()
    descriptor = os.open(os.environ[OUT_VARIABLE], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(descriptor, line)
    finally:
        os.close(descriptor)


def _close_module(part: str) -> None:
    if not _module:
        return
    own, reaped = cpu_seconds()
    _append({'kind': 'module', 'part': part, 'module': _module['name'],
             'worker': os.environ.get('PYTEST_XDIST_WORKER', ''),
             'self': round(own - _module['own'], 2),
             'children': round(reaped - _module['reaped'], 2),
             'wall': round(time.monotonic() - _module['wall'], 2), 'tests': _module['tests']})
    _module.clear()


def _part(config: pytest.Config) -> str:
    return str(config.getoption('markexpr', '') or '')


def pytest_sessionstart(session: pytest.Session) -> None:
    """Note the run's start: its wall clock and the machine's ticks."""
    if os.environ.get(OUT_VARIABLE) and not hasattr(session.config, 'workerinput'):
        _run.update(wall=time.monotonic(), ticks=machine_ticks())


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Charge the module before this test's with what it took, where this one starts another."""
    if not os.environ.get(OUT_VARIABLE):
        return
    name = item.nodeid.split('::', 1)[0]
    if _module.get('name') != name:
        _close_module(_part(item.config))
        own, reaped = cpu_seconds()
        _module.update(name=name, own=own, reaped=reaped, wall=time.monotonic(), tests=0)
    _module['tests'] += 1


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Charge the last module; where the run started, record the run."""
    if not os.environ.get(OUT_VARIABLE):
        return
    _close_module(_part(session.config))
    if _run:
        busy, steal, total = (b - a for a, b in zip(_run['ticks'], machine_ticks(), strict=True))
        cores = os.cpu_count() or 1
        workers = session.config.getoption('numprocesses', None) \
            if session.config.pluginmanager.hasplugin('xdist') else None
        _append({'kind': 'run', 'part': _part(session.config),
                 'wall': round(time.monotonic() - _run['wall'], 2),
                 'busy_cores': round(cores * busy / max(total, 1), 3),
                 'steal_cores': round(cores * steal / max(total, 1), 3), 'cores': cores,
                 'workers': int(workers or 0), 'exit': int(exitstatus)})
        _run.clear()

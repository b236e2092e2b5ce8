"""A test module that leaves a process of its own running fails, and the process is ended.

The guard is ``conftest.py``'s ``no_process_left_behind``: a robot bridge started outside a
``with`` once outlived its failed test and went on publishing states into the next modules'
graphs, which failed in turn. Checked here on a module of its own, run by pytest in a
subprocess with the workspace's conftest.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from exo_has_runtime.processes import alive

pytest_plugins = ['pytester']
pytestmark = pytest.mark.process  # the inner run starts a process

WORKSPACE = Path(__file__).resolve().parents[1]

LEAKY_MODULE = """
import subprocess
from pathlib import Path


def test_that_starts_a_process_and_forgets_it():
    process = subprocess.Popen(['sleep', '300'], start_new_session=True)
    Path('leaked.pid').write_text(str(process.pid))


def test_that_starts_nothing():
    pass
"""


def test_a_module_that_leaves_a_process_running_fails_naming_it_and_the_process_is_ended(
        pytester: pytest.Pytester) -> None:
    pytester.makeconftest((WORKSPACE / 'conftest.py').read_text())
    pytester.makepyfile(test_leaky=LEAKY_MODULE)
    result = pytester.runpytest_subprocess('-p', 'no:cacheprovider')
    result.assert_outcomes(passed=2, errors=1)  # the error: the module's teardown
    result.stdout.fnmatch_lines(['*test_leaky left 1 process(es) running, now killed: '
                                 '*sleep 300*'])
    pid = int((pytester.path / 'leaked.pid').read_text())
    assert not alive(pid)


def test_a_module_that_ends_what_it_starts_passes(pytester: pytest.Pytester) -> None:
    pytester.makeconftest((WORKSPACE / 'conftest.py').read_text())
    pytester.makepyfile(test_tidy="""
import subprocess


def test_that_ends_its_process():
    with subprocess.Popen(['sleep', '300']) as process:
        process.kill()
""")
    result = pytester.runpytest_subprocess('-p', 'no:cacheprovider')
    result.assert_outcomes(passed=1)

"""The diagnosis installs by one pip command where no ROS is, and diagnoses a CSV log there.

A fresh virtual environment (no system site-packages), an environment without the workspace's
variables (no PYTHONPATH, no AMENT_PREFIX_PATH), the packages copied as a clone has them, and
docs/diagnosing-many.md's command; then ``exo-has-diagnose`` on a truth plant's record, and a
bag of our sessions read. rclpy is not there to import: nothing on the diagnosis's path imports
it. pip fetches the dependencies from PyPI, or its cache (about 20 s with the cache, the
diagnosis then 15 s: numba compiles the model afresh).
"""

from __future__ import annotations

import ast
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import truth_plant
from rigs import rig_file

from exo_has_runtime.processes import Processes

WORKSPACE = Path(__file__).resolve().parents[1]
#: The command of docs/diagnosing-many.md, run in a clone's root.
PIP_COMMAND = 'pip install ./exo_has_common ./exo_has_sim'


def setup_requirements(package: str) -> list[str]:
    """Return what a package's setup.py declares for pip: install_requires and the extras."""
    tree = ast.parse((WORKSPACE / package / 'setup.py').read_text())
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call)
                and getattr(node.func, 'id', '') == 'setup')
    keywords = {keyword.arg: ast.literal_eval(keyword.value) for keyword in call.keywords
                if keyword.arg in ('install_requires', 'extras_require')}
    return [*keywords.get('install_requires', []),
            *(r for extra in keywords.get('extras_require', {}).values() for r in extra)]


def test_the_setup_files_declare_the_bounds_of_requirements_txt():
    bounds = {}
    for line in (WORKSPACE / 'requirements.txt').read_text().splitlines():
        if line.strip() and not line.startswith('#'):
            bounds[re.split(r'[\[<>=]', line, maxsplit=1)[0].lower()] = line.strip()
    declared = setup_requirements('exo_has_common') + setup_requirements('exo_has_sim')
    for requirement in declared:
        name = re.split(r'[\[<>=]', requirement, maxsplit=1)[0].lower()
        if name in ('setuptools', 'exo_has_common'):
            continue  # the ament template's, and the workspace's own package
        assert bounds.get(name) == requirement, f'{requirement}: requirements.txt has ' \
            f'{bounds.get(name)}'
    assert 'exo_has_common' in setup_requirements('exo_has_sim')


def run(processes: Processes, command: list[str], cwd: Path,
        timeout: float) -> subprocess.CompletedProcess[str]:
    """Run a command with only PATH and HOME of this environment; its output captured."""
    # env -i: the tether that starts it needs this environment, the command none of it.
    clean = ['env', '-i', 'PATH=/usr/local/bin:/usr/bin:/bin',
             f'HOME={os.environ.get("HOME", "/")}', 'LANG=C.UTF-8']
    return processes.run([*clean, *command], timeout=timeout, cwd=cwd, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


@pytest.mark.slow
def test_one_pip_command_installs_the_diagnosis_without_ros_and_it_diagnoses_a_csv(tmp_path):
    assert PIP_COMMAND in (WORKSPACE / 'docs' / 'diagnosing-many.md').read_text().splitlines()
    clone = tmp_path / 'clone'
    for package in ('exo_has_common', 'exo_has_sim'):
        shutil.copytree(WORKSPACE / package, clone / package,
                        ignore=shutil.ignore_patterns('__pycache__', 'build', '*.egg-info'))
    venv = tmp_path / 'venv'
    draw = truth_plant.draw(4242, 'hip', effect='none', excitation='sine_sum', duration=4.0)
    log = tmp_path / 'log.csv'
    truth_plant.write_csv(draw, log)
    python = str(venv / 'bin' / 'python')
    with Processes() as processes:
        made = run(processes, [sys.executable, '-m', 'venv', str(venv)], tmp_path, 120)
        assert made.returncode == 0, made.stdout
        pip, *arguments = shlex.split(PIP_COMMAND)
        installed = run(processes, [python, '-m', pip, '--disable-pip-version-check',
                                    *arguments], clone, 900)
        assert installed.returncode == 0, installed.stdout[-3000:]
        ros = run(processes, [python, '-c', 'import rclpy'], tmp_path, 60)
        assert 'ModuleNotFoundError' in ros.stdout
        # The plant node's command came too: one line saying what it needs, no traceback.
        plant = run(processes, [str(venv / 'bin' / 'plant')], tmp_path, 60)
        assert plant.returncode == 2, plant.stdout
        assert plant.stdout.startswith('plant: the plant node needs ROS 2 Jazzy, and rclpy is '
                                       'not installed here'), plant.stdout
        assert 'Traceback' not in plant.stdout
        out = tmp_path / 'diagnosis.json'
        diagnosed = run(processes, [str(venv / 'bin' / 'exo-has-diagnose'), str(log), '--joint',
                                    'hip', '--params', str(rig_file('hip')), '--load-mass',
                                    '50', '--json', str(out), '-q'], tmp_path, 300)
        assert diagnosed.returncode == 0, diagnosed.stdout[-3000:]
        assert diagnosed.stdout.startswith('cause: none')
        assert json.loads(out.read_text())['verdict'] == 'none'
        # A bag of our sessions, its message types from the definitions it embeds.
        bag = WORKSPACE / 'bags' / 'example_diagnosis' / 'bag'
        read = run(processes, [python, '-c', 'from exo_has_sim.diagnosis.data import read_bag; '
                               f'print(read_bag({str(bag)!r}, "left_hip").samples)'],
                   tmp_path, 120)
        assert read.stdout.strip() == '4000', read.stdout[-3000:]
        # --scheduler without Dask: told what to install.
        batch = run(processes, [str(venv / 'bin' / 'exo-has-diagnose'), str(log), '--summary',
                                str(tmp_path / 'summary'), '--scheduler', 'tcp://127.0.0.1:9'],
                    tmp_path, 120)
        assert batch.returncode == 1
        assert "pip install 'dask[distributed]'" in batch.stdout

"""The main job, ``exo-has demo``, as the README runs it: a session, its bag and its report."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from exo_has_common.bag import bag_summary

pytestmark = pytest.mark.process  # every test here starts processes


def test_the_demo_records_a_session_and_ends_with_the_path_of_its_report(tmp_path):
    result = subprocess.run(
        [sys.executable, '-m', 'exo_has_runtime.cli', 'demo', '--durations', '3', '3',
         '--output', str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path, check=False)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    report = Path(result.stdout.rstrip().splitlines()[-1])
    assert report.name == 'report.md' and report.is_file(), output
    assert 'trial 2/2: squat' in output  # progress was shown
    text = report.read_text()
    assert '| right_knee | 2 squat |' in text and '## Safety events' in text
    bag = report.parent.parent / 'bag'
    summary = bag_summary(bag)
    topics = {topic.topic for topic in summary.topics}
    assert {'/joint_reference', '/left_hip/has_state', '/right_knee/has_command'} <= topics

"""Diagnoses of a truth plant's record as a user runs them: the command, its JSON document.

Shared by the acceptance tests of the diagnosis (test_hidden_effects.py,
test_detection_limits.py), whose spawned processes import it as they import the truth plants;
their pool (:func:`diagnosis_pool`, conftest.py) and what a module queues in it
(:class:`Queued`) by test_hidden_effects_position_only.py and
test_third_truth_plant_diagnosis.py too.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections.abc import Iterator
from contextlib import contextmanager
from multiprocessing.pool import AsyncResult, Pool
from pathlib import Path
from typing import Any

from rigs import rig_file

from exo_has_runtime.tether import tie_to_parent
from exo_has_sim.diagnosis.batch import single_threaded
from exo_has_sim.diagnosis.cli import STRUCTURE_STATUS, main


def diagnose_csv(path: Path, joint_type: str, load_mass: float, out: Path) -> dict:
    """Diagnose a CSV log with the bench's parameters file of the joint type; its JSON document.

    ``load_mass`` [kg] is the mass the cylinder moves; the document is written to ``out``.
    """
    code = main([str(path), '--joint', joint_type, '--params', str(rig_file(joint_type)),
                 '--load-mass', str(load_mass), '--json', str(out), '-q'])
    # A verdict that the model's structure does not describe the data names no cause: on
    # these plants, which the structure does describe, it counts as a miss (and as a false
    # alarm on a draw without an effect).
    assert code in (0, STRUCTURE_STATUS)
    doc = json.loads(out.read_text())
    assert (code == STRUCTURE_STATUS) == (doc['verdict'] == 'structure')
    return doc


@contextmanager
def diagnosis_pool() -> Iterator[Pool]:
    """Give a pool of one process per core, each computing on one thread (as a batch's).

    Spawned, not forked: the test process may hold rclpy's threads from earlier tests, and a
    fork copies their locks mid-use.
    """
    with single_threaded():
        # Tethered: a worker ends with the test run, even one killed by SIGKILL, rather than
        # diagnosing on for minutes.
        pool = multiprocessing.get_context('spawn').Pool(os.cpu_count() or 1, tie_to_parent,
                                                         (os.getpid(),))
    with pool:
        yield pool


class Queued(dict[str, AsyncResult[Any]]):
    """A module's diagnoses queued in its pool (conftest.py): async results by name.

    ``folder`` holds their files. A diagnosis queued on another's result is added meanwhile.
    """

    def __init__(self, folder: Path, **results: AsyncResult[Any]) -> None:
        super().__init__(results)
        self.folder = folder

    def wait(self) -> None:
        """Wait until every diagnosis queued has ended, those added while waiting too."""
        waited: set[str] = set()
        while pending := [name for name in list(self) if name not in waited]:
            for name in pending:
                self[name].wait()
                waited.add(name)

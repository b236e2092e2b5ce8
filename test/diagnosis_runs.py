"""Diagnoses of a truth plant's record as a user runs them: the command, its JSON document.

Shared by the acceptance tests of the diagnosis (test_hidden_effects.py,
test_detection_limits.py), whose spawned processes import it as they import the truth plants.
"""

from __future__ import annotations

import json
from pathlib import Path

from rigs import rig_file

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

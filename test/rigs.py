"""The test bench the first and second truth plants simulate, as its parameters files.

The bench carries the HAS module the project assumed before issue 26 (a 14 mm bore, 130 mm
stroke cylinder in a linkage sized for the paper's 58 mm walking stroke), not the searched
design the exoskeleton's files now carry: the truth plants' excitations, the hidden-effect
rates and the detection limits were calibrated on it, and a diagnosis of its data is given
its file, as a user gives the file of a rig of their own (``exo-has diagnose --params``).
"""

from __future__ import annotations

from pathlib import Path

from exo_has_common.joints import JOINT_TYPES
from exo_has_sim.parameters import HasParameters, load_parameters

RIG_DIR = Path(__file__).resolve().parent / 'bench_rig'


def rig_file(joint_type: str) -> Path:
    """Return the bench's parameters file of a joint type (``'hip'`` or ``'knee'``)."""
    if joint_type not in JOINT_TYPES:
        msg = f'joint_type must be one of {JOINT_TYPES}, got {joint_type!r}'
        raise ValueError(msg)
    return RIG_DIR / f'{joint_type}.yaml'


def rig_parameters(joint_type: str) -> HasParameters:
    """Return the bench's parameter set of a joint type."""
    return load_parameters(rig_file(joint_type))

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
from exo_has_sim.parameters import CONFIG_DIR, HasParameters, load_parameters

RIG_DIR = Path(__file__).resolve().parent / 'bench_rig'
#: The files of the hip and knee the project ships (issue 26's searched design: 12 mm bore,
#: 40 mm stroke), around which the truth plants can draw instead (issue 38).
SHIPPED_DIR = CONFIG_DIR


def rig_file(joint_type: str, folder: Path | None = None) -> Path:
    """Return the parameters file of a joint type (``'hip'`` or ``'knee'``).

    From ``folder`` (default :data:`RIG_DIR`, the bench's; :data:`SHIPPED_DIR` the shipped).
    """
    if joint_type not in JOINT_TYPES:
        msg = f'joint_type must be one of {JOINT_TYPES}, got {joint_type!r}'
        raise ValueError(msg)
    return (RIG_DIR if folder is None else Path(folder)) / f'{joint_type}.yaml'


def rig_parameters(joint_type: str, folder: Path | None = None) -> HasParameters:
    """Return the parameter set of a joint type (the bench's, or ``folder``'s)."""
    return load_parameters(rig_file(joint_type, folder))


def motion_scale(joint_type: str, folder: Path | None = None) -> float:
    """Return the factor by which the truth plants shrink their excitations for ``folder``.

    The plants' excitations were calibrated on the bench's 130 mm stroke (the squat of the
    first plant uses up to 105 mm of it); on a shorter cylinder every excursion, velocity and
    acceleration about the stroke's middle is scaled by the ratio of the strokes, so the
    motion uses the same share of the stroke (1 on the bench itself).
    """
    if folder is None:
        return 1.0
    return min(1.0, rig_parameters(joint_type, folder).stroke
               / rig_parameters(joint_type).stroke)

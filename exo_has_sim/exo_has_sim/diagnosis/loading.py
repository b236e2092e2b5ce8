"""Reading a record (a CSV log or a bag) and building the plant that diagnoses it.

The plant is :class:`~exo_has_sim.diagnosis.has_plant.HasPlant` with the joint type's parameter
set or a parameters file, or :class:`~exo_has_sim.diagnosis.mass_plant.MassPlant`.
"""

from __future__ import annotations

import math
from pathlib import Path

from exo_has_common.joints import JOINT_TYPES, joint_type_of
from exo_has_sim.diagnosis.data import Limits, read_bag, read_csv
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.mass_plant import MassPlant
from exo_has_sim.diagnosis.plants import WindowedModel
from exo_has_sim.errors import DiagnosisError, MeasurementError
from exo_has_sim.parameters import load_parameters

#: The exoskeleton's joints (as exo_has_common.topics.JOINT_NAMES, without importing it).
JOINT_NAMES = ('left_hip', 'left_knee', 'right_hip', 'right_knee')


def load_plant(source: str | Path, plant: str = 'has', joint: str | None = None,
               load_mass: float | None = None, params: str | Path | None = None,
               constant_load: bool = False, speed_input: bool = False) -> WindowedModel:
    """Read a CSV log or a bag and build the plant to diagnose it with.

    Parameters
    ----------
    source : str or Path
        A CSV file, or a rosbag2 directory (or ``.mcap`` file).
    plant : str
        ``'has'`` (the project's HAS model) or ``'mass'`` (a generic mass).
    joint : str or None
        In a bag, the joint whose topics are read (default: the only one recorded). For the
        HAS, a joint name or type (``hip``, ``knee``) also picks the nominal parameter set.
    load_mass : float or None
        Mass moved by the cylinder [kg] (HAS: replaces the parameter set's; mass plant: the
        start of the mass's fit, default 50 kg).
    params : str, Path or None
        A parameters file instead of the joint type's set (HAS).
    constant_load : bool
        The user's word that an unmeasured load does not vary (HAS; see
        :attr:`~exo_has_sim.diagnosis.has_plant.HasPlant.unidentifiable`).
    speed_input : bool
        Drive the HAS's pump by the measured motor speed instead of the command through the
        motor's loop (:class:`~exo_has_sim.diagnosis.has_plant.HasPlant`).

    Raises
    ------
    MeasurementError
        For bad data (naming the problem) or an ambiguous joint.
    exo_has_sim.errors.ParameterError
        For a bad parameters file.
    exo_has_common.errors.BagError
        For an unreadable bag.

    """
    path = Path(source)
    is_bag = path.is_dir() or path.suffix == '.mcap'
    if load_mass is not None and not (math.isfinite(load_mass) and load_mass > 0.0):
        msg = f'--load-mass must be a positive mass in kg, got {load_mass!r}'
        raise MeasurementError(msg)
    if is_bag and joint is None:
        joint = _only_joint(path)
    joint_type = 'hip'
    if joint is not None:
        joint_type = joint if joint in JOINT_TYPES else joint_type_of(joint)
    if plant == 'mass':
        if is_bag:
            raise MeasurementError('the mass plant reads CSV logs (time, force, position)')
        return MassPlant(read_csv(path, 'mass'), 50.0 if load_mass is None else load_mass)
    if plant != 'has':
        msg = f'unknown plant {plant!r}: expected has or mass'
        raise MeasurementError(msg)
    parameters = load_parameters(params if params is not None else joint_type)
    limits = Limits(parameters.stroke, parameters.motor_speed_max)
    if is_bag:
        if joint is None or joint in JOINT_TYPES:
            msg = f'name the joint to read from the bag (one of {", ".join(JOINT_NAMES)})'
            raise MeasurementError(msg)
        measurement = read_bag(path, joint, limits)
    else:
        measurement = read_csv(path, 'has', limits)
    try:
        return HasPlant(measurement, parameters, load_mass, constant_load, speed_input)
    except DiagnosisError as exc:
        raise MeasurementError(f'{measurement.source}: {exc}') from None


def recorded_joints(path: str | Path) -> list[str]:
    """Return the joints whose HAS states a bag records, sorted.

    Raises
    ------
    exo_has_common.errors.BagError
        For a missing, unfinished or unreadable bag.

    """
    from exo_has_common.bag import bag_topics

    return sorted({t.topic.strip('/').split('/')[0] for t in bag_topics(path)
                   if t.topic.endswith('/has_state')})


def _only_joint(path: Path) -> str | None:
    joints = recorded_joints(path)
    if len(joints) == 1:
        return joints[0]
    msg = (f'{path} records {len(joints)} joints ({", ".join(joints) or "none"}): choose one '
           'with --joint')
    raise MeasurementError(msg)


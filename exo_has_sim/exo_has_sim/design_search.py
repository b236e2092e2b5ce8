"""The cylinder and linkage of a joint, searched against the paper's requirements.

The paper states the pump (0.4 mL/r up to 4000 r/min, section 2.3.1), the working pressure
(18 MPa), the motor (1.8 N m peak, 2.4), the peak thrust (1770 N, 2.4) and the tasks: walking
at 0.85 strides/s and squatting at 0.5 Hz, tested under 25 kg (5.2) and simulated for the
design under 50 kg (2.4). The cylinder and the linkage (Table 1, Fig. 7) are lost.

Along a motion the hydraulics see the geometry through one quantity, the displacement per
radian ``A_A h(theta)``, h the linkage's lever arm at the joint angle theta: the cylinder
moves at ``h omega``, so the pump bounds it from above (``A_A h |omega| <= s D_p n_max``, the
share s of the pump's speed a reference may ask, the rest left to the controller), and the
working pressure from below (``M <= p_max A_A h`` for an extensor moment M the rodless chamber
carries). Both hold at every instant, with the lever arm the linkage gives there, so the
pivot radii and the angle between them shape h along the range and the bore scales it.

:func:`search` tries every catalogue cylinder (bore, rod, stroke) with every linkage of a
grid inside the envelope of a thigh and a shank (or pelvis), the tasks' range centred in the
stroke; among the designs that fit the cylinder between the pivots and keep the lever arm away
from a dead point over the whole stroke, it ranks by the smallest requirement margin, then the
next (a leximin order; margins in the logarithm of capacity over need, so twice the need and
half of it count alike). The four HASs being one module (paper 4.1), the joints share the
cylinder that leaves the worse joint best off. Where no design meets every requirement, the
chosen one misses the least, and its table says which requirement it misses and by how much.
The walking load is Winter's moment per kg of body mass times the carried mass (one leg
carries it in stance, as the paper's 2.4 says of its design case), the squatting load the
quasi-static model of :func:`~exo_has_sim.loads.squat_moments`; a flexor moment, which would
pull the rod out, asks nothing of the rodless chamber (whether the wearer or the cylinder
takes it is the load model's question, not the search's). The tracking tests' 25 kg asks half
the design mass's pressures, so the design mass's margins cover them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from exo_has_sim.gait import GaitCycle, load_gait_cycle, squat_depth
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import squat_moments
from exo_has_sim.parameters import HasParameters

FloatArray = NDArray[np.float64]

#: The paper's tasks (section 5.2) and the load of its design simulations (2.4).
STRIDE_FREQUENCY = 0.85  # Hz
SQUAT_FREQUENCY = 0.5  # Hz
SQUAT_DEPTH = {'hip': math.radians(40.0), 'knee': math.radians(70.0)}  # rad, the demo's squat
DESIGN_MASS = 50.0  # kg
#: Share of the pump's top speed a reference may ask: the PD controller adds its correction
#: on top, and a motor at its limit cannot correct (the knee's errors of issue 26).
SPEED_SHARE = 0.8
#: Cylinders of the size class: bore and its rod [m] (ISO 3320 series, rods about 0.6 bore).
CYLINDERS = ((0.010, 0.006), (0.012, 0.006), (0.014, 0.008), (0.016, 0.010), (0.018, 0.010),
             (0.020, 0.012))
#: Catalogue strokes of the size class [m]; the joints share the shortest that serves both.
STROKES = (0.020, 0.025, 0.030, 0.040, 0.050, 0.060, 0.080, 0.100)
#: Length of a cylinder beyond its stroke, fully retracted: two eyes, piston, gland [m]
#: (compact catalogue cylinders of 10-20 mm bore: 45-60 mm).
DEAD_LENGTH = 0.05
#: Stroke left unused at each end of the joint's range [m], for the end stops.
END_CLEARANCE = 0.003
#: The linkage keeps the cylinder this far from a dead point: sin(psi) at least this over the
#: range (psi the supplement of the pivots' angle at the joint; 30 deg from a dead point).
MIN_TRANSMISSION = 0.5
#: Where the pivots may sit [m]: r1 along the thigh, r2 on the pelvis frame (hip) or the shank
#: (knee), within a leg of 1.75 m (thigh and shank 0.43 m, a pelvis frame 0.15 m deep).
ENVELOPE = {'hip': ((0.08, 0.35), (0.02, 0.15)), 'knee': ((0.08, 0.35), (0.015, 0.10))}
GRID = 36  # points per linkage dimension
PHASES = 400  # samples of one cycle of a motion
GERUND = {'walk': 'walking', 'squat': 'squatting'}


@dataclass(frozen=True)
class Motion:
    """One cycle of a task for one joint, sampled evenly in time.

    Attributes
    ----------
    name : str
        ``'walk'`` or ``'squat'``.
    angle, rate : np.ndarray
        Joint angle [rad] and angular velocity [rad/s].
    moment : np.ndarray
        Extensor moment [N m] per kg carried (Winter's per kg of body mass, walking).

    """

    name: str
    angle: FloatArray
    rate: FloatArray
    moment: FloatArray


def motions(joint_type: str, gait: GaitCycle | None = None) -> tuple[Motion, ...]:
    """Return one cycle of walking (:data:`STRIDE_FREQUENCY`) and of squatting for a joint."""
    table = load_gait_cycle() if gait is None else gait
    phase = np.arange(PHASES) / PHASES
    hip, knee = table.angles_at(phase)
    angle = hip if joint_type == 'hip' else knee
    if table.hip_moment is None or table.knee_moment is None:
        msg = f'{table.source}: no {joint_type}_moment column, so no walking load'
        raise ValueError(msg)
    # The plants' loads take the same curve (GaitCycle.moments_at, closed on its 0 % value).
    hip_walk, knee_walk = table.moments_at(phase)
    walk_moment = hip_walk if joint_type == 'hip' else knee_walk
    rate = np.gradient(angle, phase[1] - phase[0]) * STRIDE_FREQUENCY
    share = squat_depth(phase)
    squat_hip, squat_knee = share * SQUAT_DEPTH['hip'], share * SQUAT_DEPTH['knee']
    squat = squat_hip if joint_type == 'hip' else squat_knee
    squat_rate = np.gradient(squat, phase[1] - phase[0]) * SQUAT_FREQUENCY
    hip_moment, knee_moment = squat_moments(squat_hip, squat_knee, 1.0)
    return (Motion('walk', angle, rate, walk_moment),
            Motion('squat', squat, squat_rate,
                   hip_moment if joint_type == 'hip' else knee_moment))


@dataclass(frozen=True)
class Design:
    """A cylinder and the linkage it drives (pivot radii and psi at mid-range)."""

    bore: float
    rod: float
    linkage: Linkage

    def parameters(self, params: HasParameters) -> HasParameters:
        """Return ``params`` with this design's geometry (pivots on the radii: ac = bd = 0)."""
        k = self.linkage
        return params.replace(bore_diameter=self.bore, rod_diameter=self.rod, stroke=k.stroke,
                              link_ac=0.0, link_co=k.r1, link_bd=0.0, link_od=k.r2,
                              angle_offset=k.psi_offset, cylinder_length_min=k.length_min)


@dataclass(frozen=True)
class Margin:
    """One requirement of a design: what it needs beside what it has.

    A ``requirement`` is what the search balances (:func:`search`), a ``limit`` what every
    design it considers must meet, and ``given`` what the design does not change (the motor
    against the pump at the working pressure), reported beside them.
    """

    id: str
    text: str
    unit: str
    need: float
    capacity: float
    kind: str  # 'requirement' (the search's), 'limit' (geometric, hard) or 'given' (not chosen)

    @property
    def ratio(self) -> float:
        """Capacity over need (met at 1 or more)."""
        return self.capacity / self.need if self.need > 0.0 else math.inf

    @property
    def met(self) -> bool:
        """Whether the capacity covers the need."""
        return self.ratio >= 1.0


@dataclass(frozen=True)
class Demand:
    """What the tasks ask of a linkage, whatever the bore.

    Attributes
    ----------
    speed : dict[str, float]
        Peak ``h |omega|`` of each task [m/s]: the cylinder's speed.
    moment_per_lever : dict[str, float]
        Peak ``M / h`` of each task per kg carried [N/kg]: the rod force of its extensor moment.
    shortest, longest : float
        Least and largest pivot-to-pivot length of the cylinder over every task [m].
    transmission : float
        Least ``sin(psi)`` over every task.

    """

    speed: dict[str, float]
    moment_per_lever: dict[str, float]
    shortest: float
    longest: float
    transmission: float


def demand(linkage: Linkage, tasks: Sequence[Motion]) -> Demand:
    """Evaluate what ``tasks`` ask of ``linkage``."""
    speed, force = {}, {}
    for task in tasks:
        lever = linkage.lever_arm(task.angle)
        speed[task.name] = float(np.max(np.abs(lever * task.rate)))
        force[task.name] = float(np.max(task.moment / lever))
    angles = np.concatenate([task.angle for task in tasks])
    lengths = linkage.cylinder_length(angles)
    return Demand(speed, force, float(np.min(lengths)), float(np.max(lengths)),
                  float(np.min(np.sin(angles + linkage.psi_offset))))


def margins(design: Design, params: HasParameters, asked: Demand) -> list[Margin]:
    """Every requirement and geometric limit of a design, need beside capacity.

    ``params`` supplies what the search does not choose: pump, motor, pressures, thrust.
    """
    area = math.pi / 4.0 * design.bore ** 2
    flow = SPEED_SHARE * params.pump_displacement * params.motor_speed_max
    k = design.linkage
    out = []
    for name, speed in asked.speed.items():
        out.append(Margin(f'{name}_speed', f'peak cylinder speed {GERUND[name]}, against '
                          f"{SPEED_SHARE:.0%} of the pump's top speed", 'm/s', speed,
                          flow / area, 'requirement'))
    for name, force in asked.moment_per_lever.items():
        out.append(Margin(f'{name}_pressure', f'rodless pressure {GERUND[name]} under '
                          f'{DESIGN_MASS:g} kg', 'Pa', force * DESIGN_MASS / area,
                          params.max_working_pressure, 'requirement'))
    out.append(Margin('thrust', 'the peak thrust at the working pressure', 'N',
                      params.peak_thrust, area * params.max_working_pressure,
                      'requirement'))
    torque = params.pump_displacement * params.max_working_pressure \
        / params.pump_mechanical_efficiency
    out.append(Margin('motor_torque', 'motor torque at the working pressure', 'N m', torque,
                      params.motor_torque_peak, 'given'))
    out.append(Margin('retracted_end', 'the shortest length of the tasks beyond the '
                      'retracted cylinder and its clearance', 'm',
                      k.length_min + END_CLEARANCE, asked.shortest, 'limit'))
    out.append(Margin('extended_end', 'the extended cylinder, less its clearance, beyond the '
                      'longest length of the tasks', 'm', asked.longest + END_CLEARANCE,
                      k.length_min + k.stroke, 'limit'))
    near, far = _transmission_lengths(k)
    out.append(Margin('extended_stop', "the extended cylinder short of the pivots' dead "
                      'point by the least transmission', 'm', k.length_min + k.stroke, far,
                      'limit'))
    out.append(Margin('retracted_stop', 'the retracted cylinder long of the folded dead '
                      'point by the least transmission', 'm', near, k.length_min, 'limit'))
    out.append(Margin('cylinder_fits', 'the retracted cylinder between the pivots', 'm',
                      k.stroke + DEAD_LENGTH, k.length_min, 'limit'))
    out.append(Margin('transmission', 'sin(psi) over the range, away from a dead point', '',
                      MIN_TRANSMISSION, asked.transmission, 'limit'))
    return out


def _transmission_lengths(linkage: Linkage) -> tuple[float, float]:
    """Shortest and longest pivot distances [m] with sin(psi) at :data:`MIN_TRANSMISSION`.

    Between them the cylinder keeps its lever arm; the end stops lie within them too.
    """
    psi = math.asin(MIN_TRANSMISSION)
    folded, straight = math.pi - psi, psi
    lengths = linkage.cylinder_length(np.array([folded, straight]) - linkage.psi_offset)
    return float(lengths[0]), float(lengths[1])


def _placed(linkage: Linkage, asked: Demand, stroke: float) -> Linkage | None:
    """Give a linkage a cylinder of ``stroke``, the tasks' range in the middle of it.

    The retracted length is centred between the shortest that still reaches the tasks'
    longest length and the longest that leaves their shortest one clear, both end stops where
    the linkage keeps its least transmission (:func:`_transmission_lengths`); None where no
    length does.
    """
    near, far = _transmission_lengths(linkage)
    low = max(asked.longest + END_CLEARANCE - stroke, near)
    high = min(asked.shortest - END_CLEARANCE, far - stroke)
    if low > high:
        return None
    return replace(linkage, stroke=stroke, length_min=0.5 * (low + high))


#: Requirement margins closer than this (in the logarithm) count as equal.
TIE = 1e-3
#: Catalogue strokes tried per linkage: the shortest that holds its tasks, and the next.
STROKES_TRIED = 2


@dataclass(frozen=True)
class Choice:
    """A joint's chosen design, its margins and how it ranks (:func:`_score`)."""

    design: Design
    margins: list[Margin]
    score: tuple[float, ...]


def _score(found: Sequence[Margin]) -> tuple[float, ...] | None:
    """Rank a design: its requirement margins smallest first, then its least limit margin.

    Compared as tuples, the design with the larger smallest margin wins, and on a tie the
    larger next one (a leximin order): where the bore alone sets the smallest (the thrust),
    the linkage still balances the pump's speed against the pressure. None where a limit is
    not met.
    """
    if not all(m.met for m in found if m.kind == 'limit'):
        return None
    logs = sorted(round(math.log(m.ratio) / TIE) * TIE for m in found
                  if m.kind == 'requirement')
    return (*logs, min(math.log(m.ratio) for m in found if m.kind == 'limit'))


#: A cylinder: bore, rod and stroke [m].
Cylinder = tuple[float, float, float]


def best_linkages(params: HasParameters, gait: GaitCycle | None = None,
                  grid: int = GRID) -> dict[Cylinder, Choice]:
    """Find a joint's best linkage for each cylinder (:data:`CYLINDERS`, :data:`STROKES`).

    The linkages are a grid of ``grid`` points in each of r1, r2 (over :data:`ENVELOPE`) and
    psi at mid-range (40 to 140 deg), each with the :data:`STROKES_TRIED` shortest catalogue
    strokes that hold its tasks; a cylinder with no linkage meeting every limit is left out.
    """
    tasks = motions(params.joint_type, gait)
    angles = np.concatenate([task.angle for task in tasks])
    middle = 0.5 * (float(np.min(angles)) + float(np.max(angles)))
    (r1_low, r1_high), (r2_low, r2_high) = ENVELOPE[params.joint_type]
    best: dict[Cylinder, Choice] = {}
    for r1 in np.geomspace(r1_low, r1_high, grid):
        for r2 in np.geomspace(r2_low, r2_high, grid):
            for psi_mid in np.radians(np.linspace(40.0, 140.0, grid)):
                probe = Linkage(0.0, float(r1), 0.0, float(r2), float(psi_mid) - middle, 0.0,
                                0.0)
                asked = demand(probe, tasks)
                needed = asked.longest - asked.shortest + 2.0 * END_CLEARANCE
                for stroke in [s for s in STROKES if s >= needed][:STROKES_TRIED]:
                    linkage = _placed(probe, asked, stroke)
                    if linkage is None:
                        continue
                    for bore, rod in CYLINDERS:
                        design = Design(bore, rod, linkage)
                        found = margins(design, params, asked)
                        score = _score(found)
                        key = (bore, rod, stroke)
                        if score is not None and (key not in best or score > best[key].score):
                            best[key] = Choice(design, found, score)
    return best


def search(joints: Sequence[HasParameters], gait: GaitCycle | None = None,
           grid: int = GRID) -> dict[str, Choice]:
    """Choose one cylinder for every joint and each joint's linkage (see the module).

    The four HASs are one module (paper 4.1: 2.5 kg each), so the joints share the cylinder:
    the one whose worst joint's score (:func:`_score`) is best, each joint with its best
    linkage for it.

    Returns
    -------
    dict[str, Choice]
        Each joint type's choice.

    Raises
    ------
    ValueError
        If no cylinder has a linkage meeting every limit for every joint.

    """
    options = {params.joint_type: best_linkages(params, gait, grid) for params in joints}
    shared = [c for c in next(iter(options.values()))
              if all(c in found for found in options.values())]
    if not shared:
        msg = (f'no cylinder of {len(CYLINDERS)} bores and {len(STROKES)} strokes has a '
               f'linkage in the envelope that meets every limit of every joint '
               f'({", ".join(options)})')
        raise ValueError(msg)
    cylinder = max(shared, key=lambda c: min(found[c].score for found in options.values()))
    return {joint: found[cylinder] for joint, found in options.items()}


def lever_at_mid(linkage: Linkage, params: HasParameters) -> float:
    """Lever arm [m] at the middle of the joint's tasks' range of angles."""
    angles = np.concatenate([task.angle for task in motions(params.joint_type)])
    return float(linkage.lever_arm(0.5 * (np.min(angles) + np.max(angles))))


def region(choice: Choice, params: HasParameters, bores: FloatArray,
           scales: FloatArray) -> dict[str, FloatArray]:
    """Each margin's ratio over bores [m] and the chosen linkage scaled by ``scales``.

    Scaling both pivot radii scales every length of the linkage, and so its lever arm along
    the whole range, with its shape kept: the chart a designer reads, bore against lever arm.

    Returns
    -------
    dict[str, np.ndarray]
        Ratio (capacity over need) of every margin, shape (len(scales), len(bores)); not the
        ends', which are placed on the scaled range and met by construction.

    """
    tasks = motions(params.joint_type)
    base = choice.design.linkage
    out: dict[str, FloatArray] = {}
    for i, scale in enumerate(scales):
        linkage = replace(base, co=base.co * scale, od=base.od * scale, ac=base.ac * scale,
                          bd=base.bd * scale, length_min=base.length_min * scale,
                          stroke=base.stroke * scale)
        asked = demand(linkage, tasks)
        for j, bore in enumerate(bores):
            for m in margins(Design(float(bore), choice.design.rod, linkage), params, asked):
                if m.id.endswith('_end'):
                    continue
                out.setdefault(m.id, np.full((len(scales), len(bores)), np.nan))[i, j] = m.ratio
    return out

"""Joint-angle references for walking and squatting, both legs, with smooth starts and stops.

Walking follows a normative gait cycle (Winter's table by default, or any table of the same
shape) at a stride frequency; the right leg runs half a cycle behind the left. A trial starts
and ends standing: the motion's amplitude about the standing pose ramps in and out with a
smoothstep, so angle and angular velocity are continuous.

No normative squat curve is at hand, so squatting is generated: hip and knee flex together
along a raised cosine ``depth * (1 - cos(2 pi f t)) / 2`` from standing to a partial squat and
back (zero angular velocity at the top and the bottom), at 0.5 Hz by default, the paper's
squatting frequency (section 5.2). The default depth (hip 40 deg, knee 70 deg) stays inside the
assumed linkage ranges of exo_has_sim's parameter sets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from exo_has_sim.gait import GaitCycle, squat_depth
from exo_has_sim.loads import squat_moments

FloatArray = NDArray[np.float64]
JOINTS = ('left_hip', 'left_knee', 'right_hip', 'right_knee')


@dataclass(frozen=True)
class TrialPlan:
    """One trial: a motion between a smooth start and a smooth stop.

    Attributes
    ----------
    motion : str
        ``'walk'``, ``'squat'`` or ``'stand'``.
    duration : float
        Length of the trial including the ramps [s].
    ramp : float
        Length of the start and of the stop ramp [s].
    stride_frequency : float
        Walking strides per second [Hz] (the paper: 0.85).
    squat_frequency : float
        Squats per second [Hz] (the paper: 0.5).
    squat_hip, squat_knee : float
        Flexion at the bottom of a squat [rad].

    """

    motion: str
    duration: float
    ramp: float = 1.0
    stride_frequency: float = 0.85
    squat_frequency: float = 0.5
    squat_hip: float = math.radians(40.0)
    squat_knee: float = math.radians(70.0)

    def __post_init__(self) -> None:
        if self.motion not in ('walk', 'squat', 'stand'):
            msg = f'unknown motion {self.motion!r}: expected walk, squat or stand'
            raise ValueError(msg)
        for name in ('duration', 'stride_frequency', 'squat_frequency'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f'{name} must be positive and finite, got {value!r}'
                raise ValueError(msg)
        if not (math.isfinite(self.ramp) and 0.0 <= self.ramp <= self.duration / 2.0):
            msg = f'ramp must lie within [0, duration / 2], got {self.ramp!r}'
            raise ValueError(msg)


def _smoothstep(u: FloatArray) -> FloatArray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def envelope(plan: TrialPlan, t: FloatArray) -> FloatArray:
    """Amplitude of the motion about standing, 0 to 1, over trial time t [s]."""
    if plan.ramp == 0.0:
        return np.where((t >= 0.0) & (t <= plan.duration), 1.0, 0.0)
    rise = _smoothstep(t / plan.ramp)
    fall = _smoothstep((plan.duration - t) / plan.ramp)
    return np.minimum(rise, fall)


def joint_angles(plan: TrialPlan, gait: GaitCycle, t: FloatArray,
                 standing: FloatArray | None = None) -> FloatArray:
    """Return the reference angles [rad] of the four joints (order :data:`JOINTS`) at t [s].

    Parameters
    ----------
    plan : TrialPlan
        The trial.
    gait : GaitCycle
        Normative walking cycle.
    t : FloatArray
        Times from the start of the trial [s].
    standing : FloatArray or None
        Standing pose (hip, knee) [rad]; default both 0.

    Returns
    -------
    FloatArray
        Shape (len(t), 4).

    """
    times = np.asarray(t, dtype=float)
    stand = np.zeros(2) if standing is None else np.asarray(standing, dtype=float)
    weight = envelope(plan, times)[:, None]
    if plan.motion == 'walk':
        phase = times * plan.stride_frequency
        left = np.column_stack(gait.angles_at(phase))
        right = np.column_stack(gait.angles_at(phase + 0.5))
        motion = np.hstack([left, right]) - np.tile(stand, 2)
    elif plan.motion == 'squat':
        depth = squat_depth(plan.squat_frequency * times)
        leg = np.column_stack([depth * plan.squat_hip, depth * plan.squat_knee]) - stand
        motion = np.hstack([leg, leg])
    else:
        motion = np.zeros((len(times), 4))
    return np.tile(stand, 2) + weight * motion


def walking_moments(gait: GaitCycle, phase: FloatArray, amplitude: FloatArray) -> FloatArray:
    """Return walking's extensor moments per kilogram of carried mass [N m/kg], four joints.

    The gait table's moments at the left leg's phase (cycles) and half a cycle behind it for
    the right leg, times the trial's envelope ``amplitude`` (0 to 1).

    Returns
    -------
    FloatArray
        Shape (len(phase), 4), in the order of :data:`JOINTS`.

    """
    phase = np.atleast_1d(np.asarray(phase, dtype=float))
    n = len(phase)
    hip, knee = gait.moments_at(np.concatenate((phase, phase + 0.5)))  # both legs at once
    moments = np.column_stack((hip[:n], knee[:n], hip[n:], knee[n:]))
    return np.atleast_1d(np.asarray(amplitude, dtype=float))[:, None] * moments


def squatting_moments(angles: FloatArray) -> FloatArray:
    """Return squatting's extensor moments per kilogram of carried mass [N m/kg], four joints.

    The quasi-static squat's (:func:`exo_has_sim.loads.squat_moments`) at the left leg's
    posture in ``angles`` (shape (n, 4) [rad], order of :data:`JOINTS`), both legs alike.
    """
    angles = np.atleast_2d(np.asarray(angles, dtype=float))
    hip, knee = squat_moments(angles[:, 0], angles[:, 1], 1.0)
    return np.column_stack([hip, knee, hip, knee])


def joint_moments(plan: TrialPlan, gait: GaitCycle, t: FloatArray,
                  standing: FloatArray | None = None) -> FloatArray:
    """Return the extensor moments per kilogram of carried mass [N m/kg] of the four joints.

    Walking: :func:`walking_moments` at each time's phase and envelope; squatting:
    :func:`squatting_moments` at the reference's posture, which the envelope already shapes.
    Either ramps in and out with the motion. Standing: zero.

    Returns
    -------
    FloatArray
        Shape (len(t), 4), in the order of :data:`JOINTS`.

    """
    times = np.asarray(t, dtype=float)
    if plan.motion == 'walk':
        return walking_moments(gait, times * plan.stride_frequency, envelope(plan, times))
    if plan.motion == 'squat':
        return squatting_moments(joint_angles(plan, gait, times, standing))
    return np.zeros((len(times), 4))


def joint_velocities(plan: TrialPlan, gait: GaitCycle, t: FloatArray, dt: float = 1e-4,
                     standing: FloatArray | None = None) -> FloatArray:
    """Return reference angular velocities [rad/s], central differences of joint_angles."""
    times = np.asarray(t, dtype=float)
    ahead = joint_angles(plan, gait, times + dt, standing)
    behind = joint_angles(plan, gait, times - dt, standing)
    return (ahead - behind) / (2.0 * dt)


@dataclass(frozen=True)
class Schedule:
    """Trials run back to back from standing, then standing until stopped.

    Attributes
    ----------
    plans : tuple[TrialPlan, ...]
        The trials, in order.
    standing : tuple[float, float]
        Standing pose (hip, knee) [rad] before, between and after the trials.

    """

    plans: tuple[TrialPlan, ...]
    standing: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.plans:
            msg = 'a schedule needs at least one trial'
            raise ValueError(msg)

    @property
    def starts(self) -> FloatArray:
        """Start time of each trial from the start of the schedule [s]."""
        durations = np.array([plan.duration for plan in self.plans])
        return np.concatenate([[0.0], np.cumsum(durations)[:-1]])

    @property
    def duration(self) -> float:
        """Length of all trials together [s]."""
        return float(sum(plan.duration for plan in self.plans))

    def trial_at(self, t: float) -> int:
        """Index of the trial running at t [s], or -1 before the first and after the last."""
        if t < 0.0 or t >= self.duration:
            return -1
        return int(np.searchsorted(self.starts, t, side='right') - 1)

    def phase_at(self, t: float) -> tuple[str, float, float]:
        """Return the motion at t [s], its cycle fraction in [0, 1) and its envelope (0 to 1).

        Standing (before, between and after the trials, or a ``stand`` trial): phase and
        envelope 0.
        """
        trial = self.trial_at(t)
        if trial < 0 or self.plans[trial].motion == 'stand':
            return 'stand', 0.0, 0.0
        plan = self.plans[trial]
        local = t - float(self.starts[trial])
        frequency = plan.stride_frequency if plan.motion == 'walk' else plan.squat_frequency
        amplitude = float(envelope(plan, np.array([local]))[0])
        return plan.motion, (local * frequency) % 1.0, amplitude

    def moments(self, gait: GaitCycle, t: FloatArray) -> FloatArray:
        """Moments per kilogram of carried mass [N m/kg] of the four joints at times t [s]."""
        times = np.atleast_1d(np.asarray(t, dtype=float))
        result = np.zeros((len(times), 4))
        stand = np.array(self.standing)
        for plan, start in zip(self.plans, self.starts, strict=True):
            inside = (times >= start) & (times < start + plan.duration)
            if np.any(inside):
                result[inside] = joint_moments(plan, gait, times[inside] - start, stand)
        return result

    def references(self, gait: GaitCycle, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Angles [rad] and angular velocities [rad/s] of the four joints at times t [s].

        Each trial starts and ends standing, so the references are continuous across trials.
        """
        times = np.atleast_1d(np.asarray(t, dtype=float))
        stand = np.array(self.standing)
        angles = np.tile(np.tile(stand, 2), (len(times), 1))
        rates = np.zeros((len(times), 4))
        for plan, start in zip(self.plans, self.starts, strict=True):
            inside = (times >= start) & (times < start + plan.duration)
            if np.any(inside):
                local = times[inside] - start
                angles[inside] = joint_angles(plan, gait, local, stand)
                rates[inside] = joint_velocities(plan, gait, local, standing=stand)
        return angles, rates


class ReferenceSample(NamedTuple):
    """What the gait publisher sends at one instant, each list in the order of :data:`JOINTS`.

    Attributes
    ----------
    angles, rates : list of float
        Reference angles [rad] and angular velocities [rad/s].
    motion : str
        ``'walk'``, ``'squat'`` or ``'stand'``.
    phase : float
        Cycle fraction in [0, 1) (:meth:`Schedule.phase_at`).
    amplitude : float
        The trial's envelope, 0 to 1.
    moments : list of float
        Extensor moments per kilogram of carried mass [N m/kg] at ``phase`` and ``amplitude``
        walking, at the posture of ``angles`` squatting.

    """

    angles: list[float]
    rates: list[float]
    motion: str
    phase: float
    amplitude: float
    moments: list[float]


class ReferenceTable:
    """A schedule's references sampled ahead, one block at a time, for a real-time publisher.

    Evaluating the splines for every sample costs about half a millisecond; a block of one
    second at ``step`` is evaluated at once, and angles and angular velocities in between are
    interpolated linearly. The moments are not: the gait table's moment curves have corners
    (heel strike) where an interpolated moment misses the one at the sample's phase (a
    session's test once found 3.8e-3 N m/kg); each sample's moments are evaluated at its own
    phase and posture.

    Parameters
    ----------
    schedule : Schedule
        The trials.
    gait : GaitCycle
        Normative walking cycle.
    step : float
        Grid step [s]; 1 ms keeps the interpolation error of the walking references below
        1e-4 rad.

    """

    def __init__(self, schedule: Schedule, gait: GaitCycle, step: float = 1e-3) -> None:
        self.schedule = schedule
        self.gait = gait
        self.step = step
        self._per_block = round(1.0 / step)
        self._block = -1
        self._angles = np.zeros((0, 4))
        self._rates = np.zeros((0, 4))

    def sample(self, t: float) -> ReferenceSample:
        """Return the references, the phase and the moments of the four joints at t [s]."""
        index = t / self.step
        block = int(index // self._per_block)
        if block != self._block:
            grid = (block * self._per_block + np.arange(self._per_block + 1.0)) * self.step
            self._angles, self._rates = self.schedule.references(self.gait, grid)
            self._block = block
        local = index - block * self._per_block
        k = min(int(local), self._per_block - 1)
        w = local - k
        angles = (1.0 - w) * self._angles[k] + w * self._angles[k + 1]
        rates = (1.0 - w) * self._rates[k] + w * self._rates[k + 1]
        motion, phase, amplitude = self.schedule.phase_at(t)
        if motion == 'walk':
            moments = walking_moments(self.gait, np.array([phase]), np.array([amplitude]))[0]
        elif motion == 'squat':
            moments = squatting_moments(angles[None, :])[0]
        else:
            moments = np.zeros(4)
        return ReferenceSample([float(a) for a in angles], [float(r) for r in rates], motion,
                               phase, amplitude, [float(m) for m in moments])

"""Reading a recorded session back as arrays, and its tracking statistics (ROS-free).

Times are the messages' header stamps [s] (the nodes' clocks), so reference and state line up
however late the recorder received them. Joint angles come from the cylinder positions through
each joint's linkage (paper Eq. 1), the inverse of what the controller does with references.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from exo_has_common.bag import default_typestore, read_messages
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    GAIT_PHASE_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_driver.events import SafetyKind, Severity
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters, load_parameters

FloatArray = NDArray[np.float64]

STATE_FIELDS = ('position', 'velocity', 'pressure_a', 'pressure_b', 'motor_speed',
                'motor_speed_command', 'load_force', 'valve_mode')


@dataclass(frozen=True)
class RecordedEvent:
    """A safety event as recorded."""

    t: float  # s
    joint: str
    kind: int
    severity: int
    value: float
    limit: float
    latched: bool
    text: str
    phase: int = 0  # start; bags recorded before the field existed have none


@dataclass
class SessionData:
    """A session's signals.

    Attributes
    ----------
    reference_t : FloatArray
        Reference stamps [s], shape (K,).
    reference : FloatArray
        Reference angles [rad], shape (K, 4), columns in JOINT_NAMES order.
    states : dict
        Per joint, a dict of arrays: ``t`` [s] and each of STATE_FIELDS (HasState units).
    commands : dict
        Per joint: ``t`` [s], ``motor_speed`` [rad/s], ``enable`` (0/1).
    events : list[RecordedEvent]
        Safety events in time order.
    counts : dict
        Messages per topic.
    gait : dict
        The gait publisher's phases (exo_has_msgs/GaitPhase), where recorded: ``t`` [s],
        ``motion`` (its MOTION_* value), ``phase`` and ``amplitude``, and per joint the moment per
        kilogram of carried mass [N m/kg] under the joint's name.
    start : float
        Stamp of the first reference [s]: the start of the trials.

    """

    reference_t: FloatArray
    reference: FloatArray
    states: dict[str, dict[str, FloatArray]]
    commands: dict[str, dict[str, FloatArray]]
    events: list[RecordedEvent] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    gait: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def start(self) -> float:
        """Stamp of the first reference [s]."""
        return float(self.reference_t[0]) if len(self.reference_t) else math.nan


def _stamp(message: object) -> float:
    stamp = message.header.stamp  # type: ignore[attr-defined]
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def read_session(bag: str | Path) -> SessionData:
    """Read a session's bag.

    Raises
    ------
    exo_has_common.errors.ExoHasError
        For a missing or unreadable bag (raised by the bag reader, naming the problem).
    ValueError
        If the bag has no joint references.

    """
    typestore = default_typestore()
    reference_t: list[float] = []
    reference: list[list[float]] = []
    states: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    commands: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    events: list[RecordedEvent] = []
    counts: dict[str, int] = defaultdict(int)
    gait: dict[str, list[float]] = defaultdict(list)
    state_topics = {f'/{has_state_topic(j)}': j for j in JOINT_NAMES}
    command_topics = {f'/{has_command_topic(j)}': j for j in JOINT_NAMES}
    with read_messages(bag) as messages:
        for topic, msgtype, _t_ns, data in messages:
            counts[topic] += 1
            if topic == f'/{JOINT_REFERENCE_TOPIC}':
                msg = typestore.deserialize_cdr(data, msgtype)
                names = list(msg.name)
                if all(j in names for j in JOINT_NAMES):
                    reference_t.append(_stamp(msg))
                    reference.append([float(msg.position[names.index(j)])
                                      for j in JOINT_NAMES])
            elif topic in state_topics:
                msg = typestore.deserialize_cdr(data, msgtype)
                series = states[state_topics[topic]]
                series['t'].append(_stamp(msg))
                for name in STATE_FIELDS:
                    series[name].append(float(getattr(msg, name)))
            elif topic in command_topics:
                msg = typestore.deserialize_cdr(data, msgtype)
                series = commands[command_topics[topic]]
                series['t'].append(_stamp(msg))
                series['motor_speed'].append(float(msg.motor_speed))
                series['enable'].append(float(msg.enable))
            elif topic == f'/{GAIT_PHASE_TOPIC}':
                msg = typestore.deserialize_cdr(data, msgtype)
                names = list(msg.joints)
                if all(j in names for j in JOINT_NAMES) and \
                        len(msg.moment_per_mass) == len(names):
                    gait['t'].append(_stamp(msg))
                    for name in ('motion', 'phase', 'amplitude'):
                        gait[name].append(float(getattr(msg, name)))
                    for j in JOINT_NAMES:
                        gait[j].append(float(msg.moment_per_mass[names.index(j)]))
            elif topic == f'/{SAFETY_EVENT_TOPIC}':
                msg = typestore.deserialize_cdr(data, msgtype)
                events.append(RecordedEvent(
                    _stamp(msg), msg.joint, int(msg.kind), int(msg.severity), float(msg.value),
                    float(msg.limit), bool(msg.latched), msg.text,
                    int(getattr(msg, 'phase', 0))))
    if not reference_t:
        msg_text = f'{bag}: no joint references on /{JOINT_REFERENCE_TOPIC}'
        raise ValueError(msg_text)

    def arrays(table: dict[str, dict[str, list[float]]]) -> dict[str, dict[str, FloatArray]]:
        return {joint: {k: np.asarray(v, dtype=float) for k, v in series.items()}
                for joint, series in table.items()}

    return SessionData(np.asarray(reference_t), np.asarray(reference), arrays(states),
                       arrays(commands), sorted(events, key=lambda e: e.t), dict(counts),
                       {k: np.asarray(v, dtype=float) for k, v in gait.items()})


def joint_parameters(files: Mapping[str, str | Path] | None = None) -> dict[str, HasParameters]:
    """Each joint's parameter set: the shipped ones, or ``files`` by joint type."""
    chosen = files or {}
    return {joint: load_parameters(chosen.get(joint_type_of(joint), joint_type_of(joint)))
            for joint in JOINT_NAMES}


def linkages(params: Mapping[str, HasParameters] | None = None) -> dict[str, Linkage]:
    """Each joint's linkage, from its parameter set (default: the shipped ones)."""
    chosen = joint_parameters() if params is None else params
    return {joint: Linkage.from_parameters(chosen[joint]) for joint in JOINT_NAMES}


@dataclass(frozen=True)
class Tracking:
    """Joint tracking error (actual minus reference) over a time window, in degrees."""

    joint: str
    segment: str
    samples: int
    rms: float
    minimum: float
    maximum: float
    cylinder_rms: float  # m
    saturated: float  # share of the window's motor speed commands at the motor's limit

    @property
    def peak(self) -> float:
        """Largest error magnitude [deg]."""
        return max(abs(self.minimum), abs(self.maximum))


def joint_angles(data: SessionData, joint: str, linkage: Linkage) -> tuple[FloatArray, FloatArray]:
    """Stamps [s] and measured joint angles [rad] of a joint."""
    series = data.states[joint]
    return series['t'], np.asarray(linkage.angle(series['position']), dtype=float)


def tracking(data: SessionData, segments: Sequence[tuple[str, float, float]],
             params: Mapping[str, HasParameters] | None = None) -> list[Tracking]:
    """Tracking statistics per joint and per segment ``(name, start, end)`` [s from start].

    The reference is interpolated at the state stamps. A window with no state is skipped.
    ``params``: each joint's parameter set (default: the shipped ones), whose linkage gives
    the angles and whose motor speed limit ``saturated`` counts the controller's commands at,
    within a part in a million (where no command was recorded, as on the robot side whose loop
    commands the bus itself, the commands the states say the drives took).
    """
    chosen = joint_parameters() if params is None else params
    links = linkages(chosen)
    limits = {joint: chosen[joint].motor_speed_max for joint in JOINT_NAMES}
    rows = []
    for index, joint in enumerate(JOINT_NAMES):
        if joint not in data.states:
            continue
        t, angle = joint_angles(data, joint, links[joint])
        ref = np.interp(t, data.reference_t, data.reference[:, index])
        x = data.states[joint]['position']
        x_ref = np.asarray(links[joint].position(ref, check=False), dtype=float)
        if joint in data.commands:
            command_t, speed = data.commands[joint]['t'], data.commands[joint]['motor_speed']
        else:
            command_t, speed = t, data.states[joint]['motor_speed_command']
        at_limit = np.abs(speed) >= limits[joint] * (1 - 1e-6)
        for name, start, end in segments:
            inside = (t >= data.start + start) & (t < data.start + end)
            if not np.any(inside):
                continue
            error = np.degrees(angle[inside] - ref[inside])
            sent = (command_t >= data.start + start) & (command_t < data.start + end)
            saturated = float(np.mean(at_limit[sent])) if np.any(sent) else math.nan
            rows.append(Tracking(joint, name, int(np.sum(inside)),
                                 float(np.sqrt(np.mean(error ** 2))), float(error.min()),
                                 float(error.max()),
                                 float(np.sqrt(np.mean((x[inside] - x_ref[inside]) ** 2))),
                                 saturated))
    return rows


def rates(data: SessionData) -> dict[str, float]:
    """Mean message rate of each state and command topic [Hz], from the header stamps."""
    result = {}
    for kind, table in (('has_state', data.states), ('has_command', data.commands)):
        for joint, series in table.items():
            t = series['t']
            if len(t) > 1:
                result[f'/{joint}/{kind}'] = (len(t) - 1) / float(t[-1] - t[0])
    if len(data.reference_t) > 1:
        span = float(data.reference_t[-1] - data.reference_t[0])
        result[f'/{JOINT_REFERENCE_TOPIC}'] = (len(data.reference_t) - 1) / span
    return result


def final_stop(events: Sequence[RecordedEvent]) -> RecordedEvent | None:
    """Return the FATAL event whose stop still held when the record ended, or None.

    A stop is the first FATAL event after the last release (a RESET event that is not
    latched). A release that another source refused (its next event still latched: the driver
    keeps its own stop while a drive is in fault) leaves the stop where it was. A hold (the
    ERROR latched on a lost reference) is not a stop: the joints stay under control.
    """
    stop = released = None
    for event in sorted(events, key=lambda e: e.t):
        if event.severity >= Severity.FATAL:
            stop = stop or event
        elif event.kind == SafetyKind.RESET and not event.latched:
            stop, released = None, stop or released
        elif event.latched and stop is None and released is not None \
                and event.severity == Severity.WARN:
            stop = released  # a refusal: its source still holds the stop it had
    return stop

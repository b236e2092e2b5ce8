"""The datagrams between the robot loop and its ROS bridge: struct-packed, versioned, checked.

Free of ROS. One message a datagram, little-endian, behind an 8-byte header: the magic
``b'XH'``, the format :data:`VERSION`, the message kind and a sequence number (uint32, per
sender, wrapping), which tells the receiver what it lost. Joints travel as their index in
:data:`~exo_has_common.joints.JOINT_NAMES`, a drive's CiA 402 state as its index in
:data:`DRIVE_STATES`; times are seconds, angles radians, positions metres, pressures pascals.

From the bridge to the loop: :class:`Reference` (joint angles [rad] and rates [rad/s]),
:class:`ResetRequest`, :class:`BridgeStatus` (whether the reference's publisher is in the ROS
graph), :class:`GainChange`, :class:`LifecycleRequest` (a managed node's transition) and
:class:`HeldConditions` (the faults the bridge finds in the graph: a second source). From
the loop to the bridge: :class:`States` (the samples of one period), :class:`EventMessage` (a
safety event), :class:`Metrics` (the loop's timing) and :class:`LoopState` (its lifecycle
state, in answer to a request and every metrics period).

:func:`decode` refuses a malformed datagram with a :class:`MalformedDatagramError` that names
the problem (short, wrong magic or version, unknown kind or joint, a length that does not
match, a text that is not UTF-8): a receiver counts it and goes on, it never raises further.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import TypeVar

from exo_has_bringup.errors import BringupError
from exo_has_common.joints import JOINT_NAMES, JOINT_TYPES
from exo_has_driver.events import Condition, Event, Phase, SafetyKind, Severity
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.config import JointSample

MAGIC = b'XH'
#: Format version; a receiver refuses any other (both ends are built from one tree).
VERSION = 1
#: Largest datagram a receiver takes [bytes]; an event's text is cut to fit well within it.
MAX_DATAGRAM = 4096
#: Longest event text sent [bytes of UTF-8].
MAX_TEXT = 1024
#: Most conditions in one CONDITIONS message, the longest key and text of each [bytes].
MAX_CONDITIONS = 8
MAX_CONDITION_KEY = 64
MAX_CONDITION_TEXT = 200
#: Most samples in one STATES message (70 bytes each): a backlog goes in several.
MAX_SAMPLES = 32
#: The drive states a sample may report, by index.
DRIVE_STATES = (cia402.NOT_READY, cia402.SWITCH_ON_DISABLED, cia402.READY_TO_SWITCH_ON,
                cia402.SWITCHED_ON, cia402.OPERATION_ENABLED, cia402.QUICK_STOP_ACTIVE,
                cia402.FAULT_REACTION_ACTIVE, cia402.FAULT, cia402.UNKNOWN)
#: Joint index of a system-wide event (no joint).
NO_JOINT = 255

_HEADER = struct.Struct('<2sBBI')
_REFERENCE = struct.Struct('<dB')
_REFERENCE_JOINT = struct.Struct('<Bdd')
_STATUS = struct.Struct('<?')
_GAINS = struct.Struct('<Bdddd')
_STATES = struct.Struct('<dB')
# joint, stamp, position, velocity, pressures, motor speed, its command, current, valve mode,
# drive state, sensor fault, counter.
_SAMPLE = struct.Struct('<BddddddddbB?H')
_EVENT = struct.Struct('<dBBBB?ddH')
_METRICS = struct.Struct('<dQQQddddddQQ??H')
_LIFECYCLE = struct.Struct('<BI')
_CONDITIONS = struct.Struct('<B')
_CONDITION = struct.Struct('<BBddHH')
_LOOP_STATE = struct.Struct('<BI?H')
_DRIVE_STATE_INDEX = {state: index for index, state in enumerate(DRIVE_STATES)}
_JOINT_INDEX = {joint: index for index, joint in enumerate(JOINT_NAMES)}
_E = TypeVar('_E', bound=IntEnum)


class MalformedDatagramError(BringupError, ValueError):
    """A datagram that is not a message of this format; the text names what is wrong."""


class Kind(IntEnum):
    """The message kinds; the bridge's from 16 on."""

    STATES = 1
    EVENT = 2
    METRICS = 3
    LOOP_STATE = 4
    REFERENCE = 16
    RESET = 17
    BRIDGE_STATUS = 18
    GAINS = 19
    LIFECYCLE = 20
    CONDITIONS = 21


class Transition(IntEnum):
    """A managed node's transitions the loop carries out (ROS 2's lifecycle, REP 2002 style)."""

    CONFIGURE = 1  # open the bus, check and start the devices; drives disabled
    ACTIVATE = 2  # enable the drives and follow the reference
    DEACTIVATE = 3  # hold every joint where it stands, references ignored
    CLEANUP = 4  # stop the drives, release the bus


class LoopMode(IntEnum):
    """The loop's lifecycle state: the primary states of a managed node."""

    UNCONFIGURED = 1
    INACTIVE = 2
    ACTIVE = 3


@dataclass(frozen=True)
class Reference:
    """Joint references: angles [rad] and rates [rad/s] by joint, sent at ``stamp`` [s]."""

    stamp: float
    names: tuple[str, ...]
    angles: tuple[float, ...]
    rates: tuple[float, ...]


@dataclass(frozen=True)
class ResetRequest:
    """A request to release a latched stop or hold (a std_msgs/Empty on ``safety_reset``)."""


@dataclass(frozen=True)
class BridgeStatus:
    """What the bridge sees of the ROS graph: whether the reference's publisher is in it.

    A publisher that left (a gait publisher that ended) withdrew the reference: no hold.
    """

    reference_source_present: bool


@dataclass(frozen=True)
class GainChange:
    """New PD gains for every joint of a type (``hip``, ``knee``), as exo_has_control.pd's.

    Attributes
    ----------
    joint_type : str
        ``hip`` or ``knee``.
    kp : float
        Position gain [(rad/s)/m].
    kd, kff : float
        Velocity-error gain and feedforward [(rad/s)/(m/s)].
    speed_limit : float
        Motor speed saturation [rad/s].

    """

    joint_type: str
    kp: float
    kd: float
    kff: float
    speed_limit: float


@dataclass(frozen=True)
class LifecycleRequest:
    """A transition asked of the loop, numbered ``request`` (> 0) for its answer."""

    transition: Transition
    request: int


@dataclass(frozen=True)
class HeldConditions:
    """The faults the bridge finds now, in place of those it sent before (none: cleared).

    Each is a :class:`~exo_has_driver.events.Condition` whose key is a string (a topic, cut to
    :data:`MAX_CONDITION_KEY` bytes), its text cut to :data:`MAX_CONDITION_TEXT` bytes; at most
    :data:`MAX_CONDITIONS` of them (two topics of each of four joints).
    """

    conditions: tuple[Condition, ...]


@dataclass(frozen=True)
class LoopState:
    """The loop's lifecycle state, answering the request ``request`` (0: a report).

    Attributes
    ----------
    mode : LoopMode
        The state the loop is in now.
    request : int
        The request answered; 0 in the reports sent every metrics period.
    ok : bool
        Whether the transition asked was carried out (or was not needed).
    text : str
        Why it was refused or failed (the device, object or drive state named), else empty.

    """

    mode: LoopMode
    request: int
    ok: bool
    text: str = ''


@dataclass(frozen=True)
class States:
    """The samples completed in one period of the loop, taken at loop time ``t`` [s]."""

    t: float
    samples: tuple[JointSample, ...]


@dataclass(frozen=True)
class EventMessage:
    """A safety event of the loop or its master, raised at loop time ``t`` [s]."""

    t: float
    event: Event


@dataclass(frozen=True)
class Metrics:
    """How the loop keeps its period, since it started, at loop time ``t`` [s].

    Attributes
    ----------
    t : float
        Loop time [s].
    periods, missed, late : int
        Periods run, periods missed (no cycle in them), cycles later than half a period.
    lateness_p99, lateness_p999, lateness_max : float
        Release lateness of the cycles [s] (exo_has_common.timing.PeriodMonitor).
    longest_gap : float
        Longest time between two cycles, that is between two bus commands [s].
    compute_max : float
        Longest time a cycle of the loop took [s].
    compute_mean : float
        Mean time a cycle took [s].
    dropped : int
        Datagrams the loop dropped for want of a reader or room.
    malformed : int
        Datagrams the loop received and refused.
    stopped, holding : bool
        Whether a stop is latched; whether the joints hold (a stale reference).
    problem : str
        The last refused datagram or gain change, empty if none.

    """

    t: float
    periods: int
    missed: int
    late: int
    lateness_p99: float
    lateness_p999: float
    lateness_max: float
    longest_gap: float
    compute_max: float
    compute_mean: float
    dropped: int
    malformed: int
    stopped: bool
    holding: bool
    problem: str = ''


Inbound = (Reference | ResetRequest | BridgeStatus | GainChange | LifecycleRequest
           | HeldConditions)
Outbound = States | EventMessage | Metrics | LoopState
Message = Inbound | Outbound


def kind_of(message: Message) -> Kind:
    """Return the kind of a message."""
    return _KIND_OF[type(message)]


def _header(kind: Kind, sequence: int) -> bytes:
    return _HEADER.pack(MAGIC, VERSION, kind, sequence & 0xFFFFFFFF)


def _text(text: str, limit: int = MAX_TEXT) -> bytes:
    data = text.encode('utf-8')
    if len(data) > limit:
        data = data[:limit - 3].decode('utf-8', 'ignore').encode('utf-8') + b'...'
    return data


def _joint_index(joint: str) -> int:
    index = _JOINT_INDEX.get(joint)
    if index is None:
        msg = f'unknown joint {joint!r}: expected one of {", ".join(JOINT_NAMES)}'
        raise MalformedDatagramError(msg)
    return index


def encode(message: Message, sequence: int = 0) -> bytes:
    """Pack a message into one datagram, numbered ``sequence``.

    Raises
    ------
    MalformedDatagramError
        For an unknown joint or joint type, references of unequal lengths, or more than
        :data:`MAX_SAMPLES` samples.

    """
    if isinstance(message, Reference):
        count = len(message.names)
        if not len(message.angles) == len(message.rates) == count or count > len(JOINT_NAMES):
            msg = (f'a reference needs as many angles and rates as names (at most '
                   f'{len(JOINT_NAMES)}): {count} names, {len(message.angles)} angles, '
                   f'{len(message.rates)} rates')
            raise MalformedDatagramError(msg)
        return b''.join([_header(Kind.REFERENCE, sequence),
                         _REFERENCE.pack(message.stamp, count),
                         *(_REFERENCE_JOINT.pack(_joint_index(name), angle, rate)
                           for name, angle, rate in zip(message.names, message.angles,
                                                        message.rates, strict=True))])
    if isinstance(message, ResetRequest):
        return _header(Kind.RESET, sequence)
    if isinstance(message, BridgeStatus):
        return _header(Kind.BRIDGE_STATUS, sequence) + _STATUS.pack(
            message.reference_source_present)
    if isinstance(message, GainChange):
        if message.joint_type not in JOINT_TYPES:
            msg = f'unknown joint type {message.joint_type!r}: expected hip or knee'
            raise MalformedDatagramError(msg)
        return _header(Kind.GAINS, sequence) + _GAINS.pack(
            JOINT_TYPES.index(message.joint_type), message.kp, message.kd, message.kff,
            message.speed_limit)
    if isinstance(message, LifecycleRequest):
        return _header(Kind.LIFECYCLE, sequence) + _LIFECYCLE.pack(message.transition,
                                                                   message.request)
    if isinstance(message, HeldConditions):
        return _encode_conditions(message, sequence)
    if isinstance(message, LoopState):
        text = _text(message.text)
        return b''.join([_header(Kind.LOOP_STATE, sequence), _LOOP_STATE.pack(
            message.mode, message.request, message.ok, len(text)), text])
    if isinstance(message, States):
        if len(message.samples) > MAX_SAMPLES:
            msg = f'{len(message.samples)} samples in one message, over {MAX_SAMPLES}'
            raise MalformedDatagramError(msg)
        return b''.join([_header(Kind.STATES, sequence),
                         _STATES.pack(message.t, len(message.samples)),
                         *(_pack_sample(sample) for sample in message.samples)])
    if isinstance(message, EventMessage):
        event = message.event
        text = _text(event.text)
        joint = _joint_index(event.joint) if event.joint else NO_JOINT
        return b''.join([_header(Kind.EVENT, sequence),
                         _EVENT.pack(message.t, joint, event.kind, event.severity, event.phase,
                                     event.latched, event.value, event.limit, len(text)),
                         text])
    problem = _text(message.problem)
    return b''.join([_header(Kind.METRICS, sequence), _METRICS.pack(
        message.t, message.periods, message.missed, message.late, message.lateness_p99,
        message.lateness_p999, message.lateness_max, message.longest_gap, message.compute_max,
        message.compute_mean, message.dropped, message.malformed, message.stopped,
        message.holding, len(problem)), problem])


def _encode_conditions(message: HeldConditions, sequence: int) -> bytes:
    conditions = message.conditions
    if len(conditions) > MAX_CONDITIONS:
        msg = f'{len(conditions)} conditions in one message, over {MAX_CONDITIONS}'
        raise MalformedDatagramError(msg)
    parts = [_header(Kind.CONDITIONS, sequence), _CONDITIONS.pack(len(conditions))]
    for condition in conditions:
        if not isinstance(condition.key, str):
            msg = f'a condition key must be a string to be sent, got {condition.key!r}'
            raise MalformedDatagramError(msg)
        key = _text(condition.key, MAX_CONDITION_KEY)
        text = _text(condition.text, MAX_CONDITION_TEXT)
        joint = _joint_index(condition.joint) if condition.joint else NO_JOINT
        parts += [_CONDITION.pack(joint, condition.kind, condition.value, condition.limit,
                                  len(key), len(text)), key, text]
    return b''.join(parts)


def _pack_sample(sample: JointSample) -> bytes:
    return _SAMPLE.pack(
        _joint_index(sample.joint), sample.stamp, sample.position, sample.velocity,
        sample.pressure_a, sample.pressure_b, sample.motor_speed, sample.motor_speed_command,
        sample.motor_current, sample.valve_mode,
        _DRIVE_STATE_INDEX.get(sample.drive_state, _DRIVE_STATE_INDEX[cia402.UNKNOWN]),
        sample.sensor_fault, sample.counter & 0xFFFF)


def sequence_of(data: bytes) -> int:
    """Return the sequence number of a datagram whose header :func:`decode` accepted."""
    return int(_HEADER.unpack_from(data)[3])


def decode(data: bytes) -> Message:
    """Unpack one datagram.

    Raises
    ------
    MalformedDatagramError
        Naming what is wrong with it.

    """
    if len(data) < _HEADER.size:
        msg = f'a datagram of {len(data)} bytes is shorter than the {_HEADER.size}-byte header'
        raise MalformedDatagramError(msg)
    magic, version, kind_number, _ = _HEADER.unpack_from(data)
    if magic != MAGIC:
        msg = f'a datagram starting {bytes(data[:2])!r} is not a robot loop message ({MAGIC!r})'
        raise MalformedDatagramError(msg)
    if version != VERSION:
        msg = f'a message of format version {version}, where this end speaks {VERSION}'
        raise MalformedDatagramError(msg)
    try:
        kind = Kind(kind_number)
    except ValueError:
        msg = f'a message of unknown kind {kind_number}'
        raise MalformedDatagramError(msg) from None
    body = memoryview(data)[_HEADER.size:]
    try:
        return _DECODERS[kind](body)
    except struct.error as exc:
        msg = f'a {kind.name} message whose body of {len(body)} bytes does not unpack: {exc}'
        raise MalformedDatagramError(msg) from None


def _exact(kind: str, body: memoryview, size: int) -> None:
    if len(body) != size:
        msg = f'a {kind} message with a body of {len(body)} bytes, where {size} are expected'
        raise MalformedDatagramError(msg)


def _joint_name(index: int) -> str:
    if index >= len(JOINT_NAMES):
        msg = f'joint index {index} names no joint (there are {len(JOINT_NAMES)})'
        raise MalformedDatagramError(msg)
    return JOINT_NAMES[index]


def _decode_text(kind: str, data: memoryview) -> str:
    try:
        return bytes(data).decode('utf-8')
    except UnicodeDecodeError as exc:
        msg = f'a {kind} message whose text is not UTF-8: {exc}'
        raise MalformedDatagramError(msg) from None


def _decode_reference(body: memoryview) -> Reference:
    stamp, count = _REFERENCE.unpack_from(body)
    _exact('REFERENCE', body, _REFERENCE.size + count * _REFERENCE_JOINT.size)
    joints = [_REFERENCE_JOINT.unpack_from(body, _REFERENCE.size + i * _REFERENCE_JOINT.size)
              for i in range(count)]
    return Reference(stamp, tuple(_joint_name(index) for index, _, _ in joints),
                     tuple(angle for _, angle, _ in joints), tuple(rate for _, _, rate in joints))


def _decode_reset(body: memoryview) -> ResetRequest:
    _exact('RESET', body, 0)
    return ResetRequest()


def _decode_status(body: memoryview) -> BridgeStatus:
    _exact('BRIDGE_STATUS', body, _STATUS.size)
    return BridgeStatus(*_STATUS.unpack_from(body))


def _decode_gains(body: memoryview) -> GainChange:
    _exact('GAINS', body, _GAINS.size)
    kind, kp, kd, kff, limit = _GAINS.unpack_from(body)
    if kind >= len(JOINT_TYPES):
        msg = f'joint type index {kind} names no joint type (hip 0, knee 1)'
        raise MalformedDatagramError(msg)
    return GainChange(JOINT_TYPES[kind], kp, kd, kff, limit)


def _decode_lifecycle(body: memoryview) -> LifecycleRequest:
    _exact('LIFECYCLE', body, _LIFECYCLE.size)
    transition, request = _LIFECYCLE.unpack_from(body)
    return LifecycleRequest(_enum(Transition, transition, 'LIFECYCLE'), request)


def _decode_loop_state(body: memoryview) -> LoopState:
    mode, request, ok, length = _LOOP_STATE.unpack_from(body)
    _exact('LOOP_STATE', body, _LOOP_STATE.size + length)
    return LoopState(_enum(LoopMode, mode, 'LOOP_STATE'), request, ok,
                     _decode_text('LOOP_STATE', body[_LOOP_STATE.size:]))


def _decode_conditions(body: memoryview) -> HeldConditions:
    (count,) = _CONDITIONS.unpack_from(body)
    offset = _CONDITIONS.size
    conditions = []
    for _ in range(count):
        joint, kind, value, limit, key_length, text_length = _CONDITION.unpack_from(body, offset)
        offset += _CONDITION.size
        key = _decode_text('CONDITIONS', body[offset:offset + key_length])
        offset += key_length
        text = _decode_text('CONDITIONS', body[offset:offset + text_length])
        offset += text_length
        conditions.append(Condition(key, '' if joint == NO_JOINT else _joint_name(joint),
                                    _enum(SafetyKind, kind, 'CONDITIONS'), value, limit, text))
    _exact('CONDITIONS', body, offset)
    return HeldConditions(tuple(conditions))


def _decode_states(body: memoryview) -> States:
    t, count = _STATES.unpack_from(body)
    _exact('STATES', body, _STATES.size + count * _SAMPLE.size)
    samples = []
    for i in range(count):
        (joint, stamp, position, velocity, pressure_a, pressure_b, speed, command, current,
         valve, state, fault, counter) = _SAMPLE.unpack_from(body, _STATES.size + i * _SAMPLE.size)
        if state >= len(DRIVE_STATES):
            msg = f'drive state index {state} names no CiA 402 state'
            raise MalformedDatagramError(msg)
        samples.append(JointSample(_joint_name(joint), stamp, position, velocity, pressure_a,
                                   pressure_b, speed, command, current, valve,
                                   DRIVE_STATES[state], fault, counter))
    return States(t, tuple(samples))


def _enum(enum: type[_E], value: int, kind: str = 'EVENT') -> _E:
    try:
        return enum(value)
    except ValueError:
        msg = f'a message of kind {kind} with an unknown {enum.__name__} {value}'
        raise MalformedDatagramError(msg) from None


def _decode_event(body: memoryview) -> EventMessage:
    t, joint, kind, severity, phase, latched, value, limit, length = _EVENT.unpack_from(body)
    _exact('EVENT', body, _EVENT.size + length)
    text = _decode_text('EVENT', body[_EVENT.size:])
    event = Event('' if joint == NO_JOINT else _joint_name(joint), _enum(SafetyKind, kind),
                  _enum(Severity, severity), value, limit, latched, text, _enum(Phase, phase))
    return EventMessage(t, event)


def _decode_metrics(body: memoryview) -> Metrics:
    (t, periods, missed, late, p99, p999, lateness_max, gap, compute_max, compute_mean,
     dropped, malformed, stopped, holding, length) = _METRICS.unpack_from(body)
    _exact('METRICS', body, _METRICS.size + length)
    return Metrics(t, periods, missed, late, p99, p999, lateness_max, gap, compute_max,
                   compute_mean, dropped, malformed, stopped, holding,
                   _decode_text('METRICS', body[_METRICS.size:]))


_DECODERS: dict[Kind, Callable[[memoryview], Message]] = {
    Kind.STATES: _decode_states,
    Kind.EVENT: _decode_event,
    Kind.METRICS: _decode_metrics,
    Kind.REFERENCE: _decode_reference,
    Kind.RESET: _decode_reset,
    Kind.BRIDGE_STATUS: _decode_status,
    Kind.GAINS: _decode_gains,
    Kind.LIFECYCLE: _decode_lifecycle,
    Kind.LOOP_STATE: _decode_loop_state,
    Kind.CONDITIONS: _decode_conditions,
}
_KIND_OF: dict[type, Kind] = {
    States: Kind.STATES, EventMessage: Kind.EVENT, Metrics: Kind.METRICS,
    Reference: Kind.REFERENCE, ResetRequest: Kind.RESET, BridgeStatus: Kind.BRIDGE_STATUS,
    GainChange: Kind.GAINS, LifecycleRequest: Kind.LIFECYCLE, LoopState: Kind.LOOP_STATE,
    HeldConditions: Kind.CONDITIONS,
}

"""The robot loop's datagrams: every kind round-trips; a malformed one is named, not raised on."""

from __future__ import annotations

import math
import socket
import struct

import pytest

from exo_has_bringup.robot_exchange import (
    LOOP_SOCKET,
    DatagramExchange,
    ExchangeError,
    bridge_end,
    loop_end,
)
from exo_has_bringup.robot_messages import (
    MAX_TEXT,
    VERSION,
    BridgeStatus,
    EventMessage,
    GainChange,
    HeldConditions,
    Kind,
    LifecycleRequest,
    LoopMode,
    LoopState,
    MalformedDatagramError,
    Metrics,
    Reference,
    ResetRequest,
    States,
    Transition,
    decode,
    encode,
    sequence_of,
)
from exo_has_driver.events import Condition, Event, Phase, SafetyKind, Severity
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.config import JointSample
from exo_has_sim.valve import ValveMode

SAMPLE = JointSample('right_knee', 1764245337.125, 0.0213, -0.004, 3.2e6, 0.25e6, -41.5, -40.0,
                     2.75, ValveMode.ASSIST, cia402.OPERATION_ENABLED, False, 65535)
MESSAGES = [
    Reference(12.5, ('left_hip', 'right_knee'), (0.25, -0.5), (1.5, 0.0)),
    Reference(0.0, (), (), ()),
    ResetRequest(),
    BridgeStatus(True),
    BridgeStatus(False),
    GainChange('knee', 50e3, 10.0, 0.0, 300.0),
    States(3.25, (SAMPLE, JointSample('left_hip', 1.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                      ValveMode.FREE, cia402.FAULT, True, 0))),
    EventMessage(7.0, Event('left_knee', SafetyKind.SAFETY_VALVE_OPEN, Severity.FATAL, 21.0e6,
                            20.0e6, True, 'left_knee: safety valve open — chamber A',
                            Phase.START)),
    EventMessage(8.0, Event('', SafetyKind.STALE_REFERENCE, Severity.ERROR, 0.21, 0.2, True,
                            'stale reference', Phase.CHANGE)),
    Metrics(9.0, 1800, 2, 3, 0.0004, 0.0011, 0.0123, 0.0177, 0.0008, 0.0002, 5, 1, False,
            True, 'a datagram of 3 bytes is shorter than the 8-byte header'),
    LifecycleRequest(Transition.CLEANUP, 0xFFFFFFFF),
    LoopState(LoopMode.INACTIVE, 3, True),
    LoopState(LoopMode.UNCONFIGURED, 1, False, 'drive of left_knee (node 3) in fault 0x7121'),
    HeldConditions(()),
    HeldConditions((Condition('/left_hip/has_command', 'left_hip', SafetyKind.SECOND_SOURCE,
                              2.0, 1.0, 'left_hip: second source: 2 publishers on '
                              '/left_hip/has_command (/pd_controller, the robot loop)'),
                    Condition('/x', '', SafetyKind.STALE_COMMAND, math.nan, math.nan, 'ü'))),
]


@pytest.mark.parametrize('message', MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_kind_round_trips(message) -> None:
    data = encode(message, sequence=0xFFFFFFFF + 7)
    assert _equal_with_nans(decode(data), message)
    assert sequence_of(data) == 6  # wraps at 32 bits


def _equal_with_nans(a: object, b: object) -> bool:
    return a == b or repr(a) == repr(b)  # nan != nan, but their reprs agree


def test_a_message_naming_an_unknown_joint_cannot_be_encoded_in_a_condition_either() -> None:
    condition = Condition('/t', 'left_elbow', SafetyKind.SECOND_SOURCE, 2.0, 1.0, 'x')
    with pytest.raises(MalformedDatagramError, match="unknown joint 'left_elbow'"):
        encode(HeldConditions((condition,)))
    with pytest.raises(MalformedDatagramError, match='key must be a string'):
        encode(HeldConditions((Condition(('second source', '/t'), '', SafetyKind.SECOND_SOURCE,
                                         2.0, 1.0, 'x'),)))


def test_an_event_without_value_keeps_its_nans_and_a_long_text_is_cut() -> None:
    event = Event('', SafetyKind.RESET, Severity.INFO, math.nan, math.nan, False, 'x' * 5000)
    decoded = decode(encode(EventMessage(1.0, event)))
    assert isinstance(decoded, EventMessage)
    assert math.isnan(decoded.event.value) and math.isnan(decoded.event.limit)
    assert len(decoded.event.text.encode()) == MAX_TEXT and decoded.event.text.endswith('...')


def test_a_message_naming_an_unknown_joint_cannot_be_encoded() -> None:
    with pytest.raises(MalformedDatagramError, match="unknown joint 'left_elbow'"):
        encode(Reference(0.0, ('left_elbow',), (0.0,), (0.0,)))
    with pytest.raises(MalformedDatagramError, match='as many angles and rates as names'):
        encode(Reference(0.0, ('left_hip',), (0.0, 1.0), (0.0,)))


def _header(kind: int, version: int = VERSION) -> bytes:
    return struct.pack('<2sBBI', b'XH', version, kind, 0)


REFERENCE = encode(MESSAGES[0])
EVENT = encode(MESSAGES[7])


@pytest.mark.parametrize(('data', 'problem'), [
    (b'XH\x01', 'a datagram of 3 bytes is shorter than the 8-byte header'),
    (b'{"angles": [0.1]}', "a datagram starting b'{\"' is not a robot loop message"),
    (_header(Kind.RESET, version=2), 'format version 2, where this end speaks 1'),
    (_header(99), 'unknown kind 99'),
    (_header(Kind.RESET) + b'\x00', 'a RESET message with a body of 1 bytes, where 0'),
    (REFERENCE[:-3], 'a REFERENCE message with a body of 40 bytes, where 43'),
    (_header(Kind.REFERENCE) + b'\x00', 'REFERENCE message whose body of 1 bytes does not'),
    (_header(Kind.REFERENCE) + struct.pack('<dBBdd', 0.0, 1, 9, 0.0, 0.0),
     'joint index 9 names no joint'),
    (_header(Kind.GAINS) + struct.pack('<Bdddd', 2, 1.0, 1.0, 1.0, 1.0),
     'joint type index 2 names no joint type'),
    (EVENT[:19] + b'\x63' + EVENT[20:], 'unknown Phase 99'),  # the phase's byte
    (EVENT[:-1] + b'\xff', 'text is not UTF-8'),
    (_header(Kind.LIFECYCLE) + struct.pack('<BI', 7, 1), 'unknown Transition 7'),
    (_header(Kind.LOOP_STATE) + struct.pack('<BI?H', 2, 1, True, 3) + b'ab',
     'a LOOP_STATE message with a body of 10 bytes, where 11'),
])
def test_a_malformed_datagram_is_refused_naming_the_problem(data: bytes, problem: str) -> None:
    with pytest.raises(MalformedDatagramError) as caught:
        decode(data)
    assert problem in str(caught.value)


def test_the_exchange_carries_messages_both_ways(tmp_path) -> None:
    loop, bridge = loop_end(tmp_path), bridge_end(tmp_path)
    try:
        assert bridge.send(MESSAGES[0]) and bridge.send(ResetRequest())
        assert loop.receive() == [MESSAGES[0], ResetRequest()]
        assert loop.receive() == []  # nothing waits
        assert loop.send(MESSAGES[6])
        assert bridge.receive() == [MESSAGES[6]]
        assert loop.dropped == bridge.dropped == 0
    finally:
        loop.close()
        bridge.close()
    assert not (tmp_path / LOOP_SOCKET).exists()


def test_a_send_without_a_reader_or_room_is_dropped_and_counted(tmp_path) -> None:
    loop = loop_end(tmp_path)
    try:
        assert not loop.send(MESSAGES[6])  # no bridge yet
        assert loop.dropped == 1
        bridge = bridge_end(tmp_path)
        try:
            sent = sum(loop.send(MESSAGES[6]) for _ in range(5000))  # nobody reads
            assert 0 < sent < 5000 and loop.dropped == 1 + 5000 - sent
        finally:
            bridge.close()
        assert not loop.send(MESSAGES[6])  # the bridge went away
    finally:
        loop.close()


def test_a_malformed_datagram_or_one_of_the_wrong_side_is_counted_not_raised(tmp_path) -> None:
    loop = loop_end(tmp_path)
    raw = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        raw.sendto(b'hello', str(tmp_path / LOOP_SOCKET))
        raw.sendto(encode(MESSAGES[6]), str(tmp_path / LOOP_SOCKET))  # States: the loop's own
        raw.sendto(encode(ResetRequest()), str(tmp_path / LOOP_SOCKET))
        assert loop.receive() == [ResetRequest()]
        assert loop.malformed == 2
        assert loop.problem == 'a STATES message, which this end does not take'
    finally:
        raw.close()
        loop.close()


def test_a_socket_path_too_long_is_refused_naming_it(tmp_path) -> None:
    long = tmp_path / ('d' * 120)
    with pytest.raises(ExchangeError, match='longer than 107 bytes'):
        DatagramExchange(long / 'a.sock', long / 'b.sock', ())

"""The exoskeleton split between a robot PC and an operator's laptop, with faults on the link.

One two-host session (:mod:`exo_has_bringup.hosts`; root only) walks for 26 s: 5 s
on a clean link, 4 s losing 5 % of the packets each way, 4 s losing 20 %, then a 2 s
partition (the link down), the link back, and a reset from the operator's side 1 s later.
The robot side runs the plants, the controller, the watchdog and a recorder of its own; the
operator's side the gait publisher and the recorder. The tests read both bags afterwards;
tracking is judged on the robot's, which has every state however the link fares.

The walk strides at the paper's 0.85 Hz, which the searched design of issue 26 keeps within
its motors' top speed; the plants' loads follow the gait for 25 kg, the gait phase reaching
them from the operator's side over the same link as the references.

What is to hold, and why:

- clean and lossy link: no safety event at all, and tracking within ``HIP_WALK_PEAK`` and
  ``KNEE_PEAK``: the reference is sent every 5 ms, and 20 % loss takes a few in a row at most,
  while the hold waits for ``STALE_S`` without any;
- partition: a STALE_REFERENCE hold (ERROR, not FATAL) within ``HOLD_BOUND`` of the cut,
  every joint standing still from then until the reset, even once the link is back; no FATAL
  event; the robot's bag keeps every state, the operator's says where it lost them;
- the link back: the operator's bag has states again within ``RECOVERY_BOUND`` without a
  node restarted, and after the reset the joints rejoin and track.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from session_observer import outside_stalls

from exo_has_bringup.analysis import SessionData, joint_angles, linkages, read_session, tracking
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.runner import Session
from exo_has_common.bag import bag_summary
from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import has_state_topic
from exo_has_msgs.msg import SafetyEvent

pytestmark = pytest.mark.process  # every test here starts processes

RATE = 200.0
WALK = 26.0  # s
CLEAN, LOSS_5, LOSS_20, CUT, RESTORE, RESET = 0.0, 5.0, 9.0, 13.0, 15.0, 16.0  # s, from start
STALE_S = 0.2  # s: the session's stale limit (40 periods at 200 Hz), references included
HOLD_BOUND = STALE_S + 0.25  # s: plus a check period, the event's way and a scheduling hiccup
RECOVERY_BOUND = 3.0  # s: Fast DDS resends its announcements; a lease (20 s) never expired
HELD_MOTION = 2.0  # deg: how far a held joint may drift (pressure settling, load)
STRIDE_FREQUENCY = 0.85  # Hz: see the module docstring
# Peaks in a session here on 2026-11-27 at 0.85 strides/s, with another session beside it:
# hips 0.95, knees 3.7 deg (at 20 % loss). A joint still rejoining 3 s after the reset, as one
# did before the rejoin's fix (CI, 16 deg on a hip), misses by more.
HIP_WALK_PEAK, KNEE_PEAK = 3.0, 6.0  # deg


@dataclass
class Run:
    """What the scenario did, in system time [s] (the clock of the messages' stamps)."""

    session: Session
    marks: dict[str, float]
    operator: SessionData
    robot: SessionData


@pytest.fixture(scope='module')
def run(tmp_path_factory, virtual_hosts_available) -> Run:
    session = Session(SessionConfig(
        ('walk',), (WALK,), RATE, hosts=2,
        node_arguments={'gait_publisher': ('-p', f'stride_frequency:={STRIDE_FREQUENCY}')}),
        tmp_path_factory.mktemp('two_hosts'))
    marks: dict[str, float] = {}
    session.start(show=lambda line: None)
    try:
        assert session.hosts is not None and session.started_at is not None
        steps = [(LOSS_5, 'loss_5', lambda: session.hosts.set_loss(0.05)),
                 (LOSS_20, 'loss_20', lambda: session.hosts.set_loss(0.20)),
                 (CUT, 'cut', lambda: (session.hosts.set_loss(0.0), session.hosts.cut())),
                 (RESTORE, 'restore', session.hosts.restore),
                 (RESET, 'reset', session.reset)]
        for at, name, act in steps:
            time.sleep(max(0.0, session.started_at + at - time.monotonic()))
            marks[name] = time.time()
            act()
        # The reset is a process of its own on the operator's host: its start and discovery
        # take a second or three, so it has gone out by the time reset() returns.
        marks['reset_sent'] = time.time()
        time.sleep(max(0.0, session.started_at + WALK + 1.0 - time.monotonic()))
    finally:
        codes = session.stop()
    assert codes == dict.fromkeys(codes, 0), codes
    assert session.bag is not None and session.robot_bag is not None
    return Run(session, marks, read_session(session.bag), read_session(session.robot_bag))


def window(data: SessionData, start: float, end: float) -> list:
    """Tracking rows of the session's states between two system times [s]."""
    return tracking(data, [('window', start - data.start, end - data.start)])


def assert_tracks(data: SessionData, start: float, end: float) -> None:
    """Assert the joints track between two system times [s], outside process stalls."""
    steady, _, _ = outside_stalls(data, RATE)
    rows = window(steady, start, end)
    assert len(rows) == len(JOINT_NAMES)
    for row in rows:
        # Half the window at least: a process stall leaves out its length plus a second, and
        # this VM's stalls (0.2-0.35 s, issue 11) come a few times a minute under this load.
        assert row.samples >= 0.5 * RATE * (end - start), row
        bound = HIP_WALK_PEAK if row.joint.endswith('hip') else KNEE_PEAK
        assert row.peak <= bound, row


def test_on_a_clean_link_the_two_hosts_walk_as_one_host_does_without_an_event(run):
    start = run.operator.start + 1.0  # the first second ramps up from standing
    assert_tracks(run.robot, start, run.marks['loss_5'])
    assert [e for e in run.robot.events if e.t < run.marks['cut']] == []


@pytest.mark.parametrize(('phase', 'end', 'share'), [('loss_5', 'loss_20', 0.05),
                                                     ('loss_20', 'cut', 0.20)])
def test_a_lossy_link_raises_nothing_and_the_joints_still_track(run, phase, end, share):
    start, stop = run.marks[phase] + 0.5, run.marks[end]
    assert_tracks(run.robot, start, stop)
    # The robot hears the references the link lets through: about 1 - share of them.
    heard = np.count_nonzero((run.robot.reference_t >= start) & (run.robot.reference_t < stop))
    assert heard / ((stop - start) * RATE) == pytest.approx(1.0 - share, abs=0.08)
    assert [e.text for e in run.robot.events if start <= e.t < stop] == []


def test_a_partition_holds_every_joint_within_the_bound_and_stops_nothing(run):
    cut = run.marks['cut']
    events = [e for e in run.robot.events if e.t >= cut]
    hold = events[0]
    assert (hold.kind, hold.severity, hold.latched) == (
        SafetyEvent.KIND_STALE_REFERENCE, SafetyEvent.SEVERITY_ERROR, True), hold
    assert hold.t - cut <= HOLD_BOUND, hold.t - cut
    assert not [e for e in run.robot.events if e.severity == SafetyEvent.SEVERITY_FATAL]
    links = linkages()
    for joint in JOINT_NAMES:
        # From once the joint had a few periods to stop until the reset: it stands, although
        # the reference came back with the link at RESTORE.
        t, angle = joint_angles(run.robot, joint, links[joint])
        held = (t >= hold.t + 0.2) & (t < run.marks['reset'])
        # Most of the states (plants miss a few periods on this VM, more in a stall).
        assert held.sum() > 0.7 * RATE * (run.marks['reset'] - hold.t - 0.2), joint
        drift = np.degrees(angle[held].max() - angle[held].min())
        assert drift <= HELD_MOTION, (joint, drift)


def test_the_robots_bag_keeps_every_state_while_the_operators_says_where_it_lost_them(run):
    robot = bag_summary(run.session.robot_bag)
    operator = bag_summary(run.session.bag)
    state_topics = {f'/{has_state_topic(joint)}' for joint in JOINT_NAMES}
    assert not [g for g in robot.gaps if g.topic in state_topics], robot.gaps
    # The partition's gap on each state topic; a stall of the operator's recorder may add a
    # short gap elsewhere (a clean CI run saw one 5.6 s after the cut), which is no error.
    partition = {g.topic: g for g in operator.gaps if g.topic in state_topics
                 and abs(g.start_ns * 1e-9 - run.marks['cut']) <= 0.5}
    assert set(partition) == state_topics, operator.gaps
    for gap in partition.values():
        assert 1.8 <= gap.seconds <= 2.0 + RECOVERY_BOUND, gap


def test_after_the_link_returns_discovery_recovers_and_motion_waits_for_the_reset(run):
    restore, reset = run.marks['restore'], run.marks['reset']
    for joint in JOINT_NAMES:
        after = run.operator.states[joint]['t'][run.operator.states[joint]['t'] > restore]
        assert after.size and after[0] - restore <= RECOVERY_BOUND, joint
    released = [e for e in run.robot.events if e.kind == SafetyEvent.KIND_RESET]
    assert len(released) == 1, released
    assert reset <= released[0].t <= run.marks['reset_sent'] + 0.5, released
    assert 'hold released' in released[0].text and not released[0].latched
    # Rejoined at the rejoin speed within a few seconds, then tracking as before.
    assert_tracks(run.robot, released[0].t + 3.0, run.operator.start + WALK)


def test_the_namespaces_and_their_link_are_gone_after_the_session(run):
    assert run.session.hosts is not None and run.session.hosts.hosts == {}
    links = Path('/sys/class/net')
    assert not [name.name for name in links.iterdir() if name.name.startswith('exo')]

"""The closed loop of a session through the hardware driver and simulated CAN devices.

The same controller, gait publisher and watchdog as with the plant nodes, but the joints are
the simulated COPLEY-like drives and sensor boards (``exo_has_driver.devices``, one process on
a udp_multicast CAN bus) behind the hardware driver node. The session walks for 8 s and squats
for 8 s, as ``test_session.py``; then faults are injected into the devices through their
standard input. The tests run in file order and share the session.

The session runs at 100 Hz, not the product's 200 Hz. On one machine the simulated devices
(which the robot's drives and boards run on microcontrollers of their own) and the driver
exchange 17 frames per SYNC over multicast UDP. Each process receives every frame, its own
included. At 200 Hz the whole session took 1.1 cores of a 2-vCPU VM on 2026-11-21
(bench/closed_loop.py). On 2026-11-26 this session's VM, and the CI machine, were slower for
our code: the fast simulator's walk took 0.31 s at commit a16768b, which the VM of 2026-11-25
had run in 0.15 s (bench/simulator.py), and the test suite 1138 s against 761 s. The session
at 200 Hz then took 1.8 of the 2 cores. Its loop fell to 155-185 Hz, and the master saw
every slave's heartbeat lost (a 0.17 s gap against the 0.15 s consumer time). At 100 Hz it
holds its rate.
The loop's behaviour at 200 Hz is measured by bench/closed_loop.py and bench/driver.py, where
a slow machine shows as a number, not as a failed test.

The devices and the driver's I/O thread run under SCHED_FIFO (``REALTIME_PRIORITY``), as
the drives' firmware and a robot PC's bus thread would: with a busy loop beside the session
on one of the two cores, under the default scheduler a sensor board's heartbeat once went
unheard for 0.155 s (FATAL, every joint stopped; an ad hoc session with this file's observer,
2026-11-26); under SCHED_FIFO the state samples came at most 18 ms apart and the session
ended with no fatal event.

The walk strides at the paper's 0.85 Hz: the searched design of issue 26 keeps its motors
below their top speed there (``exo-has design-check --search``). The simulated devices carry
constant loads (``SessionConfig.load_mass``; they have no gait phase), so the knee carries
its stance load through the swing as well, and at 100 Hz the loop closes through up to two
periods of delay: knee peaks of 9.4-10.0 deg in three sessions here (2026-11-27), hips
2.6, against 3.5 and 0.9 deg in the plant-node sessions under loads that follow the gait.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from session_observer import Observer, observed_session, read_so_far

from exo_has_bringup.analysis import rates, tracking
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.report import segments_of
from exo_has_bringup.runner import Session
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_control.pd import PdGains
from exo_has_sim import model
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import default_load_force
from exo_has_sim.parameters import load_parameters
from exo_has_sim.simulate import simulate_closed_loop

pytestmark = pytest.mark.process  # every test here starts processes

MOTIONS, DURATIONS = ('walk', 'squat'), (8.0, 8.0)
RATE = 100.0  # Hz: see the module docstring
STRIDE_FREQUENCY = 0.85  # Hz: see the module docstring
REALTIME_PRIORITY = 20  # SCHED_FIFO, under the kernel's threaded interrupts at 50
# The walk is judged from 3 s. The joints sink under their constant loads while the driver
# starts up (free valves): 30-36 deg with the searched design's small bore, against 12-17 deg
# before it, and rejoin the reference at the controller's rejoin speed (15 mm/s of cylinder,
# exo_has_control.tracking), which took a hip until 2.2 s into the walk in one session here.
WALK_START = 3.0  # s
WINDOWS = [(name, start + (WALK_START if name.endswith('walk') else 0.0), end)
           for name, start, end in segments_of(MOTIONS, DURATIONS)]
# A drive applies a command at the SYNC after it arrives, the driver publishes a sample at its
# tick after the SYNC, and the controller answers at its own tick: at 100 Hz up to three 10 ms
# periods between a position and the flow it commands, which sessions draw differently
# (2026-11-27, at 0.85 strides/s: knees 8.9-10.3 deg in five sessions, 13.0 in a suite run;
# no stall in any). The model walks the same with the delay as a transport delay: knees 9.4
# deg at 20 ms, 14.1 at 30 ms, hips 3.0 and 3.7, matching the sessions' figures and the
# asymmetry of their errors. The bounds are the model's at three periods plus a degree
# (loop_delay_peak); a loop that does not close through the driver misses by tens of degrees.
LOOP_DELAY = 3.0 / RATE  # s


def loop_delay_peak(kind: str, delay: float) -> float:
    """Peak walking error [deg] of the model's joint under the devices' load, delayed loop."""
    params = load_parameters(kind)
    linkage = Linkage.from_parameters(params)
    gait = load_gait_cycle()
    period = 1.0 / RATE
    t = np.arange(round(8.0 / period)) * period
    hip, knee = gait.angles_at(STRIDE_FREQUENCY * t)
    angle = hip if kind == 'hip' else knee
    x_ref = np.asarray(linkage.position(angle), dtype=float)
    load = default_load_force(params, mass=SessionConfig().load_mass[kind])
    delayed = params.with_effects(transport_delay=delay)
    gains = PdGains.paper(params)
    y0 = model.initial_state(delayed, float(x_ref[0]), load)
    run = simulate_closed_loop([delayed], y0[None], x_ref[:, None],
                               np.gradient(x_ref, period)[:, None], np.full(len(t), load),
                               np.array([[gains.kp, gains.kd, gains.kff]]), period)
    position = np.clip(run.states[1:, 0, model.X], 0.0, params.stroke)
    error = np.degrees(linkage.angle(position) - angle)
    return float(np.abs(error[t > 2.0]).max())


FAULT_BOUND = 0.25  # s: injection to the driver's FATAL event (a few 10 ms cycles + scheduling)
STOP_BOUND = 0.5  # s: injection to every motor reported below STOPPED_SPEED
STOPPED_SPEED = 2.0  # rad/s
DRIVE_FAULT, HEARTBEAT_LOST, BUS_OFF, RESET = 8, 9, 10, 13
FATAL = 3


@pytest.fixture(scope='module')
def session(tmp_path_factory):
    config = SessionConfig(
        MOTIONS, DURATIONS, RATE, hardware='can', realtime_priority=REALTIME_PRIORITY,
        node_arguments={'gait_publisher': ('-p', f'stride_frequency:={STRIDE_FREQUENCY}')})
    with observed_session(config, tmp_path_factory.mktemp('can_session')) as pair:
        yield pair


@pytest.fixture(scope='module')
def recorded(session):
    running, _observer = session
    return read_so_far(running)


def test_the_joints_track_through_the_driver_within_their_bounds(recorded):
    rows = tracking(recorded, WINDOWS)
    assert len(rows) == 8
    bounds = {kind: loop_delay_peak(kind, LOOP_DELAY) + 1.0 for kind in ('hip', 'knee')}
    assert bounds['knee'] < 16.0 and bounds['hip'] < 5.0  # deg: 15.1 and 4.7 measured here
    for row in rows:
        assert row.peak <= bounds[joint_type_of(row.joint)], (row, bounds)


def test_walking_and_squatting_through_the_driver_raise_no_fatal_event(recorded):
    assert [e for e in recorded.events if e.severity >= FATAL] == []


def test_the_driver_publishes_every_joints_state_at_the_sync_rate(recorded):
    measured = rates(recorded)
    for joint in JOINT_NAMES:
        rate = measured[f'/{joint}/has_state']
        assert rate == pytest.approx(RATE, rel=0.05), (joint, rate)


def _fatal_after(observer: Observer, start: float, kinds: tuple[int, ...]):
    def found():
        for t, event in observer.events:
            if t >= start and event.kind in kinds and event.severity == FATAL:
                return t
        return None
    return found


def _all_stopped_after(observer: Observer, start: float):
    def found():
        times = []
        for joint in JOINT_NAMES:
            slow = [t for t, state in observer.states[joint]
                    if t >= start and abs(state.motor_speed) < STOPPED_SPEED]
            if not slow:
                return None
            times.append(slow[0])
        return max(times)
    return found


def _released_after(observer: Observer, start: float):
    return lambda: next((t for t, e in observer.events if t > start and e.kind == RESET
                         and 'stop released' in e.text and not e.latched), None)


def _moving_after(observer: Observer, start: float):
    def found():
        for joint in JOINT_NAMES:
            for t, state in observer.states[joint]:
                if t > start and abs(state.motor_speed) > STOPPED_SPEED:
                    return t
        return None
    return found


def _device_motor_speeds(running: Session) -> list[float]:
    """Ask the simulated devices for their status; return every drive's motor speed [rad/s]."""
    devices = running.processes['can_devices']
    before = len(devices.output)
    devices.send('status')
    deadline = time.monotonic() + 5.0
    pattern = re.compile(r' drive \d+: .*motor (-?[\d.]+) rad/s')
    while time.monotonic() < deadline:
        speeds = [float(m.group(1)) for m in pattern.finditer(devices.output[before:])]
        if len(speeds) == len(JOINT_NAMES):
            return speeds
        time.sleep(0.05)
    msg = f'no status from the devices: {devices.output[before:]!r}'
    raise TimeoutError(msg)


def test_a_drive_fault_stops_every_motor_and_latches_until_a_reset(session):
    running, observer = session
    start = time.monotonic()
    running.processes['can_devices'].send('fault left_knee 0x2310')
    raised = observer.wait_for(_fatal_after(observer, start, (DRIVE_FAULT,)), 5.0)
    stopped = observer.wait_for(_all_stopped_after(observer, start), 5.0)
    assert raised - start < FAULT_BOUND
    assert stopped - start < STOP_BOUND, f'stopped after {stopped - start:.3f} s'
    time.sleep(0.3)  # latched: the motors stay stopped
    with observer.lock:
        speeds = [abs(s.motor_speed) for j in JOINT_NAMES for _t, s in observer.states[j][-10:]]
    assert max(speeds) < STOPPED_SPEED
    # Released on request once the fault is reset: the drives hold the standing joints again.
    reset_at = time.monotonic()
    observer.reset.publish(observer.empty())
    observer.wait_for(_released_after(observer, reset_at), 5.0)
    observer.wait_for(_moving_after(observer, reset_at), 5.0)
    dead = [name for name, p in running.processes.items() if p.process.poll() is not None]
    assert dead == []


def test_a_bus_that_stops_answering_is_a_fatal_event_and_nothing_crashes(session):
    running, observer = session
    start = time.monotonic()
    running.processes['can_devices'].send('silence all')
    raised = observer.wait_for(_fatal_after(observer, start, (HEARTBEAT_LOST, BUS_OFF)), 5.0)
    assert raised - start < FAULT_BOUND + 0.15  # the 150 ms heartbeat consumer time at most
    with observer.lock:
        fatal = [e for t, e in observer.events if t >= start and e.severity == FATAL]
    assert fatal and all(e.latched for e in fatal)
    time.sleep(0.5)
    # No state comes over a silent bus: the devices say whether the motors stopped.
    assert max(abs(speed) for speed in _device_motor_speeds(running)) < STOPPED_SPEED
    dead = [name for name, p in running.processes.items() if p.process.poll() is not None]
    assert dead == []

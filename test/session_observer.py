"""A node in a test process that watches a running session: events, commands, states.

It publishes loads and resets too. With :func:`observed_session` and :func:`read_so_far`,
shared by the integration tests of sessions.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from std_msgs.msg import Empty, Float64

from exo_has_bringup.analysis import SessionData, read_session
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.runner import Session
from exo_has_common.bag import recover_bag
from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import (
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
    load_force_topic,
)
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.profiles import SAFETY_EVENT_QOS


class Observer:
    """A node in the test process: watches events and commands, publishes loads and resets."""

    def __init__(self, states: bool = True) -> None:
        self.context = Context()
        self.context.init(['observer'])
        self.node = Node('test_observer', context=self.context)
        self.events: list[tuple[float, object]] = []
        self.commands: dict[str, list[tuple[float, float, bool]]] = defaultdict(list)
        self.lock = threading.Lock()
        self.node.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self._on_event,
                                      SAFETY_EVENT_QOS)
        self.states: dict[str, list[tuple[float, object]]] = defaultdict(list)
        for joint in JOINT_NAMES:
            self.node.create_subscription(
                HasCommand, has_command_topic(joint),
                lambda c, j=joint: self._on_command(j, c), qos_profile_sensor_data)
            if states:  # 800 messages a second into this process: only where a test reads them
                self.node.create_subscription(
                    HasState, has_state_topic(joint),
                    lambda m, j=joint: self._on_state(j, m), qos_profile_sensor_data)
        self.float64 = Float64
        self.loads = {j: self.node.create_publisher(Float64, load_force_topic(j), 10)
                      for j in JOINT_NAMES}
        self.empty = Empty
        self.reset = self.node.create_publisher(
            Empty, SAFETY_RESET_TOPIC,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except ExternalShutdownException:
            pass  # the context was shut down between the check and the spin: the end
        self.executor.shutdown()

    def _on_event(self, event: object) -> None:
        with self.lock:
            self.events.append((time.monotonic(), event))

    def _on_command(self, joint: str, command: object) -> None:
        with self.lock:
            self.commands[joint].append((time.monotonic(), command.motor_speed,
                                         command.enable))

    def _on_state(self, joint: str, state: object) -> None:
        with self.lock:
            self.states[joint].append((time.monotonic(), state))

    def wait_for(self, predicate, timeout: float) -> float:
        """Wait until predicate() returns something; return that (a time, by the callers)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                found = predicate()
            if found is not None:
                return found
            time.sleep(0.02)  # the predicates scan whole lists under the observer's lock
        msg = f'not within {timeout} s'
        raise TimeoutError(msg)

    def close(self) -> None:
        """Shut the observer's context down."""
        self.context.try_shutdown()
        self._thread.join(timeout=2.0)


@contextmanager
def observed_session(config: SessionConfig, folder: Path,
                     states: bool = True) -> Iterator[tuple[Session, Observer]]:
    """Start a session and an observer, run the trials to their end, stop both on leaving.

    ``states``: whether the observer takes the HAS states too (not only commands and events).
    """
    running = Session(config, folder)
    running.start(show=lambda line: None)
    observer = Observer(states)
    try:
        running.run(show=lambda line: None, extra=1.0)
        yield running, observer
    finally:
        observer.close()
        running.stop()


def bag_so_far(running: Session) -> Path:
    """Return where :func:`read_so_far` puts the copy of a running session's bag."""
    return Path(running.folder) / 'bag_so_far'


def read_so_far(running: Session) -> SessionData:
    """Read a running session's bag back while the session goes on standing."""
    # The bag is written by chunks: read a copy closed by recovery while the recorder is on.
    assert running.bag is not None
    copy = bag_so_far(running)
    recover_bag(running.bag, copy)
    return read_session(copy)


def outside_stalls(data: SessionData, rate: float, gap: float = 0.05,
                   settle: float = 1.0) -> tuple[SessionData, float, list[str]]:
    """Return the session without the states of the stretches a process stall disturbed.

    A stall of any node process (the plants, the controller, the gait publisher: issue 11,
    bench/README.md "Stalls") shows as a gap of over ``gap`` seconds in its stream's stamps;
    the states from its start to ``settle`` seconds after it are left out. Returned with the
    data: the seconds left out (at ``rate`` [Hz]) and each stall, described for a failure's
    message.
    """
    streams = {'reference': data.reference_t}
    streams.update({f'{joint} state': series['t'] for joint, series in data.states.items()})
    streams.update({f'{joint} command': s['t'] for joint, s in data.commands.items()})
    windows, stalls = [], []
    for name, t in streams.items():
        for i in np.flatnonzero(np.diff(t) > gap) if len(t) > 1 else ():
            windows.append((t[i], t[i + 1] + settle))
            stalls.append(f'{name} at {t[i] - data.start:.2f} s for {t[i + 1] - t[i]:.3f} s')
    states, left_out = {}, 0.0
    for joint, series in data.states.items():
        keep = np.ones(len(series['t']), dtype=bool)
        for start, end in windows:
            keep &= ~((series['t'] >= start) & (series['t'] <= end))
        states[joint] = {name: values[keep] for name, values in series.items()}
        left_out = max(left_out, float(np.sum(~keep)) / rate)
    return replace(data, states=states), left_out, stalls

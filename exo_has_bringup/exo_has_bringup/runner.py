"""An exoskeleton session without launch files: its nodes as processes, recorded to a bag.

A :class:`Session` runs a plan (:mod:`exo_has_bringup.plan`): it starts the recorder, the joints
(four plant nodes; or, with ``hardware='can'``, the simulated CAN devices and the hardware driver
in front of them), the watchdog, the PD controller and, last, the gait publisher (whose first
reference starts the trials), each with :class:`~exo_has_runtime.processes.NodeProcess` and its log
in the session folder (the nodes of :attr:`SessionConfig.composition` share one container process);
it stops them in the reverse order (SIGINT, then SIGTERM, then SIGKILL), the recorder last, so the
bag holds the whole session and is closed cleanly. The demo (``exo-has demo``) and the integration
tests run sessions.

A session owns its processes. Whatever ends its runner, nothing of it is left running:

- SIGINT, SIGTERM and SIGHUP of the runner: :func:`interrupt_on_signals` turns the last two
  into :class:`SessionInterrupted` (a ``KeyboardInterrupt``, as SIGINT raises), so the code that
  stops the session runs, and the nodes end in order within :data:`STOP_BOUND` seconds.
- SIGKILL of the runner, or its crash: each node process is tied to it
  (:mod:`exo_has_runtime.tether`) and gets SIGTERM, which it takes as SIGINT: the
  recorder closes its bag, every node ends within :data:`ORPHAN_BOUND` seconds.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from exo_has_bringup.errors import DomainInUseError
from exo_has_bringup.hosts import OPERATOR, ROBOT, VirtualHosts
from exo_has_bringup.plan import (
    NodeSpec,
    SessionConfig,
    node_names,
    node_specs,
    recorded_topics,
    robot_bag_of,
)
from exo_has_common.topics import SAFETY_RESET_TOPIC
from exo_has_runtime.processes import NodeProcess

#: Time allowed for a node to report ready [s]; a plant's first start compiles the model.
READY_TIMEOUT = 120.0

#: Longest time from SIGINT, SIGTERM or SIGHUP of a session's runner to the end of its last
#: node [s] (each stops in well under a second; tests/test_session_ownership.py times it).
STOP_BOUND = 10.0

#: Longest time from SIGKILL of a session's runner to the end of its last node [s].
ORPHAN_BOUND = 5.0


def refuse_if_occupied(config: SessionConfig, env: dict[str, str] | None = None) -> None:
    """Refuse to run a session where nodes of its names already run on its ROS domain.

    Two sessions on one domain would each take the other's messages: two sources on every
    joint, and reports that mix both. This listens for
    :func:`~exo_has_runtime.graph.census_time` seconds at most.

    Raises
    ------
    DomainInUseError
        Naming the nodes found, the domain, and how to choose another.

    """
    from exo_has_runtime.graph import nodes_on_domain  # rclpy: only where a check is made

    domain = (env or {}).get('ROS_DOMAIN_ID', os.environ.get('ROS_DOMAIN_ID', '')).strip()
    ours = node_names(config)
    found = set(nodes_on_domain(int(domain) if domain else None, wanted=ours)) & ours
    if found:
        msg = (f'ROS domain {domain or 0} already has nodes of a session: '
               f'{", ".join(sorted(found))} (another exo-has demo, or nodes started by hand). '
               'Stop them, or run this one on a domain of its own: ROS_DOMAIN_ID=<0-101> ...')
        raise DomainInUseError(msg)


class SessionInterrupted(KeyboardInterrupt):
    """The runner of a session got SIGTERM or SIGHUP: stop as on Ctrl-C (SIGINT).

    Parameters
    ----------
    signum : int
        The signal's number.

    """

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f'interrupted by {signal.Signals(signum).name}')


@contextmanager
def interrupt_on_signals() -> Iterator[None]:
    """While entered, SIGTERM and SIGHUP raise :class:`SessionInterrupted` in the main thread.

    SIGINT keeps raising ``KeyboardInterrupt``; either way the ``finally`` clauses that stop a
    session run. Only the first of these signals raises, so that a repeated SIGTERM does not
    break off the stopping it started. The previous handlers come back on exit.
    """
    raised: list[int] = []

    def interrupt(signum: int, frame: object) -> None:
        if not raised:
            raised.append(signum)
            raise SessionInterrupted(signum)

    previous = {number: signal.signal(number, interrupt)
                for number in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


class Session:
    """The nodes of a session running as processes, logs and bag in ``folder``.

    Parameters
    ----------
    config : SessionConfig
        What to run.
    folder : Path
        Session folder: ``bag/`` (when recording) and ``logs/`` go there.
    env : dict or None
        Extra environment of the node processes (ROS_DOMAIN_ID, for instance).

    """

    def __init__(self, config: SessionConfig, folder: Path,
                 env: dict[str, str] | None = None) -> None:
        self.config = config
        self.folder = Path(folder)
        self.bag = self.folder / 'bag' if config.record else None
        self.logs = self.folder / 'logs'
        self.env = env or {}
        self.processes: dict[str, NodeProcess] = {}
        self.specs: dict[str, NodeSpec] = {}
        self.started_at: float | None = None  # monotonic time the first trial starts
        # The two virtual hosts and their link, in a two-host session (from start() on).
        self.hosts: VirtualHosts | None = None
        self.robot_bag = robot_bag_of(self.bag) if self.bag and config.hosts == 2 else None

    def start(self, show: Callable[[str], None] = print) -> None:
        """Start every node in order, each once the ones before are ready.

        Raises
        ------
        TimeoutError
            If a node does not come up; its output is quoted and everything is stopped.

        """
        self.logs.mkdir(parents=True, exist_ok=True)
        specs = node_specs(self.config, self.bag)
        self.specs = {spec.name: spec for spec in specs}
        if self.config.hosts == 2:
            self.hosts = VirtualHosts()
            self.hosts.start()
            show(f'two hosts: robot {self.hosts.hosts[ROBOT].address}, operator '
                 f'{self.hosts.hosts[OPERATOR].address}, joined by a link')
        # The recorder first (it reports once it has subscribed), then the plants and the
        # controller, the watchdog once there is something to watch, and the gait publisher
        # last: the trials start when everything is up and the recorder has subscribed to
        # every topic (the gait publisher's start delay leaves it the time).
        try:
            for stage in sorted({spec.stage for spec in specs}):
                group = [spec for spec in specs if spec.stage == stage]
                for spec in group:
                    env, netns = self._placement(spec.host)
                    self.processes[spec.name] = NodeProcess(
                        spec.module, spec.arguments, env=env,
                        log_path=self.logs / f'{spec.name}.log', stdin=spec.stdin, netns=netns)
                    show(f'started {spec.name} (pid {self.processes[spec.name].process.pid})')
                # A stage starts once the one before reported ready, with no pause for
                # discovery: what needs its peers waits for them itself (the watchdog's
                # start-up grace, the gait publisher's readers, the recorder's topics below).
                for spec in group if stage > 0 else ():
                    self.processes[spec.name].wait_for_output(spec.ready, READY_TIMEOUT)
            for recorder in ('recorder', 'robot_recorder'):
                if recorder in self.processes:
                    # At least the session's own topics (load topics come when someone
                    # publishes, and the count rises by as many as discovery found at once).
                    self._wait_for_recording(recorder, len(recorded_topics(
                        commands=self.config.hardware != 'robot')))
            # The gait publisher's start delay runs once its readers have matched.
            self.process_of('gait_publisher').wait_for_output(r'trials start in', READY_TIMEOUT)
            self.started_at = time.monotonic() + self.config.start_delay
        except BaseException:
            self.stop()
            raise

    def _placement(self, host: str) -> tuple[dict[str, str], str | None]:
        """Environment and network namespace of a process on a host (None: this one)."""
        if self.hosts is None:
            return self.env, None
        placed = self.hosts.hosts[host]
        return {**self.env, **placed.environment}, placed.netns

    def _wait_for_recording(self, name: str, topics: int) -> None:
        recorder = self.processes[name]
        deadline = time.monotonic() + READY_TIMEOUT
        while True:
            counts = [int(n) for n in re.findall(r'recording (\d+) topics', recorder.output)]
            if counts and max(counts) >= topics:
                return
            if time.monotonic() > deadline or recorder.process.poll() is not None:
                msg = (f'{name} did not subscribe to {topics} topics within '
                       f'{READY_TIMEOUT:g} s; its output:\n{recorder.output}')
                raise TimeoutError(msg)
            time.sleep(0.05)

    def run(self, show: Callable[[str], None] = print, interval: float = 2.0,
            extra: float = 1.0, actions: Sequence[tuple[float, str, Callable[[], object]]] = (),
            ) -> None:
        """Let the trials run to their end (plus ``extra`` seconds), showing progress.

        ``actions``: ``(time [s from the first trial's start], what, do)``, each done once at
        its time, in order (link faults and resets in a two-host session, say).
        """
        if self.started_at is None:
            msg = 'start the session first'
            raise RuntimeError(msg)
        end = self.started_at + self.config.duration + extra
        pending = sorted(actions, key=lambda action: action[0])
        next_show = time.monotonic()
        while (now := time.monotonic()) < end:
            elapsed = now - self.started_at
            while pending and pending[0][0] <= elapsed:
                _, what, do = pending.pop(0)
                show(f'[{elapsed:5.1f} s] {what}')
                do()
            if now >= next_show:
                show(f'[{elapsed:5.1f} s / {self.config.duration:.0f} s] {self.status()}')
                dead = [name for name, p in self.processes.items()
                        if p.process.poll() is not None]
                if dead:
                    show(f'stopped unexpectedly: {", ".join(dead)}')
                next_show = now + interval
            due = [next_show, end] + ([self.started_at + pending[0][0]] if pending else [])
            time.sleep(max(0.0, min(due) - time.monotonic()))

    def status(self) -> str:
        """One line: the trial running and the safety events so far."""
        gait = self.processes.get('gait_publisher')
        trial = 'waiting'
        if gait is not None:
            lines = [ln for ln in gait.output.splitlines() if 'trial' in ln or 'done' in ln]
            if lines:
                trial = lines[-1].split(']: ', 1)[-1]
        watchdog = self.processes.get('watchdog')
        events = 0 if watchdog is None else sum(
            1 for ln in watchdog.output.splitlines() if 'ERROR' in ln or 'WARN' in ln
            or 'FATAL' in ln)
        return f'{trial}; watchdog warnings and errors: {events}'

    def stop(self) -> dict[str, int]:
        """Stop every node, the recorder last; return their exit codes by name."""
        codes = {}
        for name in reversed(list(self.processes)):
            codes[name] = self.processes[name].stop()
        if self.hosts is not None:
            self.hosts.close()
        return codes

    def reset(self, timeout: float = 15.0) -> None:
        """Ask the watchdog to release a stop or a hold, from the operator's side.

        Publishes std_msgs/Empty on ``safety_reset`` once the watchdog has matched, as ``ros2
        topic pub --once`` would, from a process on the operator's host in a two-host
        session, and waits until the watchdog acknowledged it (reliable: resent over a lossy
        link).

        Raises
        ------
        TimeoutError
            If the reset could not be sent within ``timeout`` seconds (no watchdog reached).

        """
        env, netns = self._placement(OPERATOR)
        sender = NodeProcess('exo_has_runtime.topic_tool', (
            'publish', f'/{SAFETY_RESET_TOPIC}=std_msgs/msg/Empty={{}}', '--count', '1',
            '--duration', f'{timeout:g}', '--name', 'operator_reset'), env=env, netns=netns,
            log_path=self.logs / f'reset_{time.monotonic_ns()}.log')
        try:
            code = sender.wait(timeout)
        except subprocess.TimeoutExpired:
            sender.stop()
            msg = f'no reset sent within {timeout:g} s: {sender.output}'
            raise TimeoutError(msg) from None
        if code != 0 or not re.search(r'^ACKED$', sender.output, re.MULTILINE):
            msg = (f'the reset was not acknowledged within {timeout:g} s (exit code {code}; '
                   f'no watchdog reached?): {sender.output}')
            raise TimeoutError(msg)

    def process_of(self, node: str) -> NodeProcess:
        """Return the process that runs a node (its own, or its container).

        Raises
        ------
        KeyError
            If no process of the session runs that node.

        """
        for name, spec in self.specs.items():
            if node == name or node in spec.members:
                return self.processes[name]
        msg = f'no process of this session runs a node {node!r}'
        raise KeyError(msg)

    def output(self, node: str) -> str:
        """Everything the process of a node wrote so far."""
        return self.process_of(node).output


"""An exoskeleton session without launch files: its nodes as processes, recorded to a bag.

:class:`Session` starts the recorder, the joints (four plant nodes; or, with ``hardware='can'``,
the simulated CAN devices and the hardware driver in front of them), the watchdog, the PD
controller and, last, the gait publisher (whose first reference starts the trials), each with
:class:`~exo_has_runtime.testing.processes.NodeProcess` and its log in the session folder (the
nodes of :attr:`SessionConfig.composition` share one container process); it
stops them in the reverse order (SIGINT, then SIGTERM, then SIGKILL), the recorder last, so the
bag holds the whole session and is closed cleanly. The demo (``exo-has demo``) and the
integration tests run sessions.

A session owns its processes. Whatever ends its runner, nothing of it is left running:

- SIGINT, SIGTERM and SIGHUP of the runner: :func:`interrupt_on_signals` turns the last two
  into :class:`SessionInterrupted` (a ``KeyboardInterrupt``, as SIGINT raises), so the code that
  stops the session runs, and the nodes end in order within :data:`STOP_BOUND` seconds.
- SIGKILL of the runner, or its crash: each node process is tied to it
  (:mod:`exo_has_runtime.testing.tether`) and gets SIGTERM, which it takes as SIGINT: the
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
from dataclasses import dataclass, field
from pathlib import Path

from exo_has_control.errors import DomainInUseError
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_runtime.container import ComponentSpec
from exo_has_runtime.joints import JOINT_NAMES, joint_type_of
from exo_has_runtime.testing.hosts import OPERATOR, ROBOT, VirtualHosts
from exo_has_runtime.testing.processes import NodeProcess
from exo_has_runtime.topics import (
    DIAGNOSTICS_TOPIC,
    GAIT_PHASE_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
    load_force_topic,
)

#: Time allowed for a node to report ready [s]; a plant's first start compiles the model.
READY_TIMEOUT = 120.0

#: Pause after each stage of nodes came up [s]: their first matches with the running nodes
#: settle before the next stage starts (and the watchdog starts judging).
SETTLE_TIME = 1.0

#: Longest time from SIGINT, SIGTERM or SIGHUP of a session's runner to the end of its last
#: node [s] (each stops in well under a second; tests/test_session_ownership.py times it).
STOP_BOUND = 10.0

#: Longest time from SIGKILL of a session's runner to the end of its last node [s].
ORPHAN_BOUND = 5.0

#: Nodes a session composes into one process by default (bench/README.md, "Whole system"):
#: the four simulated joints, as the hardware driver serves the four real ones from one
#: process. A crash takes the four down together, as a power loss of the robot would; the
#: watchdog, in a process of its own, sees them go stale and latches the stop.
COMPOSITION: dict[str, tuple[str, ...]] = {
    'plants': tuple(f'{joint}_plant' for joint in JOINT_NAMES)}

#: What moves the joints: plant nodes, or simulated CAN devices behind the hardware driver.
HARDWARE = ('plants', 'can')

#: Nodes that ``SessionConfig.node_arguments`` may give extra ROS arguments to.
CONFIGURABLE_NODES = ('recorder', 'pd_controller', 'watchdog', 'gait_publisher')




def recorded_topics(with_loads: bool = False) -> list[str]:
    """Absolute names of the topics a session records."""
    topics = [f'/{JOINT_REFERENCE_TOPIC}', f'/{GAIT_PHASE_TOPIC}', f'/{SAFETY_EVENT_TOPIC}',
              DIAGNOSTICS_TOPIC]
    for joint in JOINT_NAMES:
        topics += [f'/{has_command_topic(joint)}', f'/{has_state_topic(joint)}']
        if with_loads:
            topics.append(f'/{load_force_topic(joint)}')
    return topics


@dataclass(frozen=True)
class NodeSpec:
    """One node of a session: a name for its log, the module run, its ROS arguments.

    A node is composed with others (:mod:`exo_has_runtime.container`) through its class,
    ``node_class``; on its own it runs as ``python -m module``, which is what ``ros2 run``
    starts.
    """

    name: str
    module: str
    arguments: tuple[str, ...] = ()
    ready: str = r'ready'  # a line of its output that says it is up
    stage: int = 1  # nodes start by stage, each once the earlier stages are up
    stdin: bool = False  # a pipe to its standard input (the simulated devices' fault injection)
    node_class: str = ''  # package.module:Class, for composition
    members: tuple[str, ...] = ()  # the nodes a container runs (empty: just this one)
    host: str = ROBOT  # where it runs in a two-host session: robot or operator


def compose(specs: list[NodeSpec], name: str, members: tuple[str, ...]) -> list[NodeSpec]:
    """Replace the nodes named ``members`` by one container process called ``name``.

    The container starts at the earliest stage of its members and is ready once every member
    has said so.

    Raises
    ------
    ValueError
        If a member is not among the specs or cannot be composed.

    """
    by_name = {spec.name: spec for spec in specs}
    missing = [member for member in members if member not in by_name]
    if missing:
        msg = f'cannot compose {", ".join(missing)}: no such node in the session'
        raise ValueError(msg)
    parts = [by_name[member] for member in members]
    for part in parts:
        if not part.node_class or part.stdin:
            msg = f'cannot compose {part.name}: it is not a node class'
            raise ValueError(msg)
    hosts = {part.host for part in parts}
    if len(hosts) > 1:
        msg = (f'cannot compose {", ".join(members)}: they run on different hosts '
               f'({", ".join(sorted(hosts))})')
        raise ValueError(msg)
    arguments = [token for part in parts
                 for token in ComponentSpec(part.node_class, part.arguments).command_line()]
    # Every member's ready line, in any order.
    ready = '(?s)' + ''.join(f'(?=.*{part.ready})' for part in parts)
    container = NodeSpec(name, 'exo_has_runtime.container', tuple(arguments), ready=ready,
                         stage=min(part.stage for part in parts), members=members,
                         host=parts[0].host)
    # In the place of the earliest member: every spec before it stays before it.
    position = min(specs.index(part) for part in parts)
    rest = [spec for spec in specs if spec.name not in members]
    rest.insert(position, container)
    return rest


@dataclass(frozen=True)
class SessionConfig:
    """What a session runs.

    Attributes
    ----------
    motions, durations : tuple
        Trials of the gait publisher and their lengths [s].
    rate : float
        Rate of the plants and the gait publisher [Hz] (the paper: 200).
    record : bool
        Whether to record a bag.
    loads : bool
        Whether to record the load topics too (when a test publishes loads).
    plant_arguments : dict
        Extra ROS arguments per joint's plant (e.g. ``-p load_force:=...``).
    node_arguments : dict
        Extra ROS arguments per node other than the plants, by node name (e.g. ``{'recorder':
        ('-p', 'poll_period:=0.0')}``).
    start_delay : float
        Time from the moment the gait publisher's readers (controller, watchdog, recorder)
        have matched to its first reference [s]: the nodes settle at standing first.
    params : dict
        Parameters file by joint type (``'hip'``, ``'knee'``) where not the shipped one: the
        plants', the controller's and the watchdog's (with ``hardware='plants'``).
    carried_mass : float
        Mass [kg] the wearer carries, which the plants' loads follow along the gait
        (:mod:`exo_has_sim.loads`): 25 kg, the load of the paper's tracking tests (section 5.2),
        for all four joints, as both legs carry it in turn.
    load_mass : dict
        Mass [kg] each joint type's constant load is derived for on the simulated CAN devices,
        which have no gait phase: the peak extensor moment at the standing lever arm, 1099 N on
        the hips for the paper's 50 kg design case, 894 N on the knees for 25 kg.
    stale_periods : int
        Control periods without a state or command before the watchdog stops everything: 40
        (200 ms at 200 Hz), some forty times the worst tick lateness of the session's nodes
        (bench/system.py). It was 100 while Fast DDS's shared-memory transport stalled node
        processes for 333 ms whenever a process joined the domain (exo_has_runtime.dds).
    hardware : str
        ``'plants'``: one plant node per joint. ``'can'``: the hardware driver on a simulated
        CAN bus (python-can's udp_multicast) with the simulated drives and sensor boards of
        every joint in one process (``exo_has_driver.devices``), as on the robot.
    can_channel : str
        Multicast group of the simulated CAN bus; empty: a random one per session, so that
        sessions on one machine do not share a bus.
    realtime_priority : int
        SCHED_FIFO priority of the plants' loops, or of the driver's I/O thread and the
        simulated CAN devices (0: the default scheduler; see exo_has_runtime.realtime). Not
        the controller's: beside the CAN test's observer, a controller under SCHED_FIFO held
        off the driver's state publication (bench/README.md, "The controller under
        SCHED_FIFO"); ``node_arguments`` can set its ``realtime_priority``.
    hosts : int
        1: every node on this machine. 2: the robot side (joints, controller, watchdog and a
        recorder of its own, ``robot_recorder``) and the operator side (gait publisher and
        recorder) on two virtual hosts joined by a link (:mod:`exo_has_runtime.testing.hosts`;
        root only), as on a robot PC and an operator's laptop.
    composition : dict or None
        Nodes composed into one process (:mod:`exo_has_runtime.container`), as process name:
        node names; every other node runs in its own process. None: :data:`COMPOSITION`, the
        four plants in one process with the plant hardware (``{}``: every node its own
        process).

    """

    motions: tuple[str, ...] = ('walk', 'squat')
    durations: tuple[float, ...] = (10.0, 8.0)
    rate: float = 200.0
    record: bool = True
    loads: bool = False
    plant_arguments: dict[str, tuple[str, ...]] = field(default_factory=dict)
    node_arguments: dict[str, tuple[str, ...]] = field(default_factory=dict)
    start_delay: float = 2.0
    stale_periods: int = 40
    params: dict[str, str] = field(default_factory=dict)
    carried_mass: float = 25.0  # kg, exo_has_sim.loads.TRACKING_LOAD_MASS
    load_mass: dict[str, float] = field(default_factory=lambda: {'hip': 50.0, 'knee': 25.0})
    hardware: str = 'plants'
    can_channel: str = ''
    realtime_priority: int = 0
    composition: dict[str, tuple[str, ...]] | None = None
    hosts: int = 1

    def __post_init__(self) -> None:
        if self.hosts not in (1, 2):
            msg = f'hosts must be 1 or 2, got {self.hosts!r}'
            raise ValueError(msg)
        if self.hardware not in HARDWARE:
            msg = f'unknown hardware {self.hardware!r}: expected one of {", ".join(HARDWARE)}'
            raise ValueError(msg)
        kinds = sorted(set(self.params) - {'hip', 'knee'})
        if kinds:
            msg = f'params for unknown joint types {", ".join(kinds)}: expected hip or knee'
            raise ValueError(msg)
        unknown = sorted(set(self.node_arguments) - set(CONFIGURABLE_NODES))
        if unknown:
            msg = (f'node_arguments for unknown node {", ".join(unknown)}: expected among '
                   f'{", ".join(CONFIGURABLE_NODES)} (plants: plant_arguments)')
            raise ValueError(msg)

    @property
    def duration(self) -> float:
        """Length of all trials [s]."""
        return float(sum(self.durations))


def node_specs(config: SessionConfig, bag: Path | None) -> list[NodeSpec]:
    """Return the nodes of a session."""
    specs = []
    # One host: everything runs here, on the robot PC as it were.
    operator = OPERATOR if config.hosts == 2 else ROBOT
    if config.record and bag is not None:
        topics = ','.join(f"'{t}'" for t in recorded_topics(config.loads))

        def recorder(name: str, output: Path, extra: tuple[str, ...], host: str) -> NodeSpec:
            return NodeSpec(name, 'exo_has_runtime.recorder', (
                '--ros-args', '-r', f'__node:={name}', '-p', f'output:={output}', '-p',
                f'topics:=[{topics}]', *extra), ready=r'recording', stage=0,
                node_class='exo_has_runtime.recorder:Recorder', host=host)
        specs.append(recorder('recorder', bag, config.node_arguments.get('recorder', ()),
                              operator))
        if config.hosts == 2:
            # The robot keeps its own record: a partition costs the operator's bag, not this.
            specs.append(recorder('robot_recorder', robot_bag_of(bag), (), ROBOT))
    if config.hardware == 'can':
        channel = config.can_channel or random_multicast_group()
        specs.append(NodeSpec('can_devices', 'exo_has_driver.devices.main', (
            '--interface', 'udp_multicast', '--channel', channel,
            '--load-mass-hip', f'{config.load_mass["hip"]}',
            '--load-mass-knee', f'{config.load_mass["knee"]}',
            '--realtime-priority', f'{config.realtime_priority}'), ready=r'can devices ready',
            stdin=True))
        specs.append(NodeSpec('driver', 'exo_has_driver.driver_node', (
            '--ros-args', '-p', 'interface:=udp_multicast', '-p', f'channel:={channel}',
            '-p', f'rate:={config.rate}', '-p', f'realtime_priority:={config.realtime_priority}'),
            ready=r'driver ready', stage=2, node_class='exo_has_driver.driver_node:Driver'))
    else:
        for joint in JOINT_NAMES:
            kind = joint_type_of(joint)
            specs.append(NodeSpec(f'{joint}_plant', 'exo_has_sim.plant_node', (
                '--ros-args', '-r', f'__node:={joint}_plant', '-p', f'joint:={joint}',
                '-p', f'rate:={config.rate}',
                '-p', 'load_model:=gait', '-p', f'load_mass:={config.carried_mass}',
                *(('-p', f'params:={config.params[kind]}') if kind in config.params else ()),
                '-p', f'realtime_priority:={config.realtime_priority}',
                *config.plant_arguments.get(joint, ())),
                ready=rf'{joint} plant ready', node_class='exo_has_sim.plant_node:PlantNode'))
    # The controller and the watchdog take the plants' parameters files (linkage, stroke).
    files = sorted(config.params.items())
    controller = (*(token for kind, path in files for token in ('-p', f'{kind}.params:={path}')),
                  *config.node_arguments.get('pd_controller', ()))
    specs.append(NodeSpec('pd_controller', 'exo_has_control.pd_controller',
                          ('--ros-args', *controller) if controller else (),
                          ready=r'controller ready',
                          node_class='exo_has_control.pd_controller:PdController'))
    specs.append(NodeSpec('watchdog', 'exo_has_driver.watchdog', (
        '--ros-args', '-p', f'rate:={config.rate}', '-p', f'control_rate:={config.rate}',
        '-p', f'stale_periods:={config.stale_periods}',
        *(token for kind, path in files for token in ('-p', f'params_{kind}:={path}')),
        *config.node_arguments.get('watchdog', ())), stage=3,
        node_class='exo_has_driver.watchdog:Watchdog'))
    # The controller, the watchdog and the recorders take the references.
    reference_readers = 2 + int(config.record and bag is not None) * config.hosts
    motions = ','.join(f"'{m}'" for m in config.motions)
    durations = ','.join(f'{float(d)}' for d in config.durations)
    specs.append(NodeSpec('gait_publisher', 'exo_has_control.gait_publisher', (
        '--ros-args', '-p', f'motions:=[{motions}]', '-p', f'durations:=[{durations}]',
        '-p', f'rate:={config.rate}', '-p', f'start_delay:={config.start_delay}',
        '-p', f'wait_for_subscribers:={reference_readers}',
        *config.node_arguments.get('gait_publisher', ())),
        ready=r'gait publisher ready', stage=4, host=operator,
        node_class='exo_has_control.gait_publisher:GaitPublisher'))
    composition = config.composition
    if composition is None:
        composition = COMPOSITION if config.hardware == 'plants' else {}
    for name, members in composition.items():
        specs = compose(specs, name, members)
    return specs


def robot_bag_of(bag: Path) -> Path:
    """Return the robot side's own bag of a two-host session whose operator records ``bag``."""
    return bag.with_name('robot_bag')


def node_names(config: SessionConfig) -> set[str]:
    """Full names (``/name``) of the nodes a session runs."""
    bag = Path('bag') if config.record else None  # a placeholder: only the names are read
    return {f'/{name}' for spec in node_specs(config, bag)
            for name in (spec.members or (spec.name,))}


def refuse_if_occupied(config: SessionConfig, env: dict[str, str] | None = None) -> None:
    """Refuse to run a session where nodes of its names already run on its ROS domain.

    Two sessions on one domain would each take the other's messages: two sources on every
    joint, and reports that mix both. This listens for
    :data:`~exo_has_runtime.graph.CENSUS_TIME` seconds at most.

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
                for spec in group if stage > 0 else ():
                    self.processes[spec.name].wait_for_output(spec.ready, READY_TIMEOUT)
                time.sleep(SETTLE_TIME)
            for recorder in ('recorder', 'robot_recorder'):
                if recorder in self.processes:
                    # At least the session's own topics (load topics come when someone
                    # publishes, and the count rises by as many as discovery found at once).
                    self._wait_for_recording(recorder, len(recorded_topics()))
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
        sender = NodeProcess('exo_has_runtime.testing.peers', (
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


"""The plan of an exoskeleton session, without ROS: which nodes run, where and how composed.

:class:`SessionConfig` says what a session runs (trials, rate, the joints' hardware, one host
or two, faults on their link, parameter files, extra node arguments); :func:`node_specs` turns
it into the command lines of its nodes (:class:`NodeSpec`), in start order and with the nodes of
:data:`COMPOSITION` sharing one container process (:func:`compose`). Nothing here starts a
process: :mod:`exo_has_bringup.runner` runs a plan, and the tests check plans alone.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from exo_has_bringup.hosts import OPERATOR, ROBOT
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    DIAGNOSTICS_TOPIC,
    GAIT_PHASE_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    has_command_topic,
    has_state_topic,
    load_force_topic,
)
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_runtime.container import ComponentSpec

#: Nodes a session composes into one process by default (bench/README.md, "Whole system"):
#: the four simulated joints, as the hardware driver serves the four real ones from one
#: process. A crash takes the four down together, as a power loss of the robot would; the
#: watchdog, in a process of its own, sees them go stale and latches the stop.
COMPOSITION: dict[str, tuple[str, ...]] = {
    'plants': tuple(f'{joint}_plant' for joint in JOINT_NAMES)}

#: What moves the joints: plant nodes; simulated CAN devices behind the hardware driver, the
#: PD controller and the watchdog; or the same devices behind the robot loop and its bridge.
HARDWARE = ('plants', 'can', 'robot')

#: Nodes that ``SessionConfig.node_arguments`` may give extra ROS arguments to.
CONFIGURABLE_NODES = ('recorder', 'pd_controller', 'watchdog', 'gait_publisher')




def recorded_topics(with_loads: bool = False, commands: bool = True) -> list[str]:
    """Absolute names of the topics a session records.

    ``commands``: whether the joints are commanded over topics (not on the robot side, whose
    loop commands the bus itself; each state carries the speed the drive was commanded).
    """
    topics = [f'/{JOINT_REFERENCE_TOPIC}', f'/{GAIT_PHASE_TOPIC}', f'/{SAFETY_EVENT_TOPIC}',
              DIAGNOSTICS_TOPIC]
    for joint in JOINT_NAMES:
        topics += [f'/{has_command_topic(joint)}'] if commands else []
        topics.append(f'/{has_state_topic(joint)}')
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
        ``'robot'``: the same devices behind the robot loop (:mod:`.robot_main`: bus, safety
        rules and PD law in one real-time thread, no ROS) and its bridge
        (:mod:`.robot_bridge`), which take the places of the driver, the controller and the
        watchdog (the controller's node arguments, its gains, go to the bridge).
    can_channel : str
        Multicast group of the simulated CAN bus; empty: a random one per session, so that
        sessions on one machine do not share a bus.
    robot_cpus : str
        CPUs (as ``taskset -c`` takes them: ``1``, ``2-3``) that the robot loop and the
        simulated devices keep to (``hardware='robot'``; the devices also with ``'can'``),
        as a robot PC gives its loop an isolated core: the rest of the session should be kept
        off them (bench/closed_loop.py keeps itself, and so what it starts, on the others).
        Empty: any.
    can_bitrate : int
        Bit rate [bit/s] at which the CANopen master judges the bus load of its SYNC period
        (a udp_multicast bus has none of its own): 1 Mbit/s, classic CAN's top, carries the
        four joints up to about 370 Hz; a faster loop needs CAN FD or a bus per joint.
    realtime_priority : int
        SCHED_FIFO priority of the plants' loops, or of the driver's I/O thread or the robot
        loop (0: the default scheduler; see exo_has_common.realtime). The simulated CAN devices
        run one level under it (:func:`devices_priority`). Not the controller's: beside the CAN
        test's observer, a controller under SCHED_FIFO held off the driver's state publication
        (bench/README.md, "The controller under SCHED_FIFO"); ``node_arguments`` can set its
        ``realtime_priority``.
    hosts : int
        1: every node on this machine. 2: the robot side (joints, controller, watchdog and a
        recorder of its own, ``robot_recorder``) and the operator side (gait publisher and
        recorder) on two virtual hosts joined by a link (:mod:`exo_has_bringup.hosts`;
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
    can_bitrate: int = 1_000_000
    robot_cpus: str = ''
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
        topics = ','.join(f"'{t}'" for t in recorded_topics(
            config.loads, commands=config.hardware != 'robot'))

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
    if config.hardware in ('can', 'robot'):
        channel = config.can_channel or random_multicast_group()
        specs.append(NodeSpec('can_devices', 'exo_has_driver.devices.main', (
            '--interface', 'udp_multicast', '--channel', channel,
            '--load-mass-hip', f'{config.load_mass["hip"]}',
            '--load-mass-knee', f'{config.load_mass["knee"]}',
            '--realtime-priority', f'{devices_priority(config.realtime_priority)}',
            *(('--cpus', config.robot_cpus) if config.robot_cpus else ())),
            ready=r'can devices ready',
            stdin=True))
    if config.hardware == 'robot':
        specs += robot_side(config, channel)
    elif config.hardware == 'can':
        specs.append(NodeSpec('driver', 'exo_has_driver.driver_node', (
            '--ros-args', '-p', 'interface:=udp_multicast', '-p', f'channel:={channel}',
            '-p', f'rate:={config.rate}', '-p', f'bitrate:={config.can_bitrate}',
            '-p', f'realtime_priority:={config.realtime_priority}'),
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
    files = tuple(token for kind, path in sorted(config.params.items())
                  for token in ('-p', f'{kind}.params:={path}'))
    if config.hardware != 'robot':
        controller = ('-p', f'rate:={config.rate}', *files,
                      *config.node_arguments.get('pd_controller', ()))
        specs.append(NodeSpec('pd_controller', 'exo_has_control.pd_controller',
                              ('--ros-args', *controller),
                              ready=r'controller ready',
                              node_class='exo_has_control.pd_controller:PdController'))
        specs.append(NodeSpec('watchdog', 'exo_has_driver.watchdog', (
            '--ros-args', '-p', f'rate:={config.rate}', '-p', f'control_rate:={config.rate}',
            '-p', f'stale_periods:={config.stale_periods}',
            *files, *config.node_arguments.get('watchdog', ())), stage=3,
            node_class='exo_has_driver.watchdog:WatchdogNode'))
    # The controller and the watchdog (or the robot loop's bridge) and the recorders take the
    # references.
    reference_readers = (1 if config.hardware == 'robot' else 2) \
        + int(config.record and bag is not None) * config.hosts
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


def devices_priority(realtime_priority: int) -> int:
    """Return the SCHED_FIFO priority of the simulated CAN devices: one under the robot's.

    On the robot the drives and sensor boards are hardware and take no CPU from the robot PC;
    here they share its cores, and at the same priority as the bus thread they ran to the end of
    their step while it waited: the robot loop's lateness reached 2 to 4 ms at 200 Hz, its
    longest gap 8 to 9 ms, where one level under it they were 0.2 and 5.2 ms (2 busy processes
    beside, 10 s each, 2026-11-27). At priority 1 the devices take the default scheduler.
    """
    return max(realtime_priority - 1, 0)


def robot_side(config: SessionConfig, channel: str) -> list[NodeSpec]:
    """Return the robot loop and its bridge for a session on the CAN bus ``channel``.

    Their sockets are in a directory named after the bus, short enough for a socket's path
    and distinct for each session on this machine (a random bus each).
    """
    directory = Path(tempfile.gettempdir()) / f'exo_has-robot-{channel}'
    files = {kind: config.params.get(kind, kind) for kind in ('hip', 'knee')}
    gains = config.node_arguments.get('pd_controller', ())
    return [
        NodeSpec('robot_loop', 'exo_has_bringup.robot_main', (
            '--interface', 'udp_multicast', '--channel', channel, '--rate', f'{config.rate}',
            '--bitrate', f'{config.can_bitrate}',
            '--hip-params', files['hip'], '--knee-params', files['knee'],
            '--stale-periods', f'{config.stale_periods}', '--socket-dir', f'{directory}',
            '--realtime-priority', f'{config.realtime_priority}',
            *(('--cpus', config.robot_cpus) if config.robot_cpus else ())),
            ready=r'robot loop ready', stage=2),
        NodeSpec('robot_bridge', 'exo_has_bringup.robot_bridge', (
            '--ros-args', '-p', f'socket_dir:={directory}', '-p', f'rate:={config.rate}',
            *(token for kind in ('hip', 'knee') for token in ('-p', f'{kind}.params:='
                                                              f'{files[kind]}')),
            *gains), ready=r'robot bridge ready', stage=3,
            node_class='exo_has_bringup.robot_bridge:RobotBridge'),
    ]


def robot_bag_of(bag: Path) -> Path:
    """Return the robot side's own bag of a two-host session whose operator records ``bag``."""
    return bag.with_name('robot_bag')


def node_names(config: SessionConfig) -> set[str]:
    """Full names (``/name``) of the nodes a session runs."""
    bag = Path('bag') if config.record else None  # a placeholder: only the names are read
    return {f'/{name}' for spec in node_specs(config, bag)
            for name in (spec.members or (spec.name,))}

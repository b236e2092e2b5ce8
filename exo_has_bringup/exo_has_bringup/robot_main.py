r"""The robot loop's process: the bus, the CANopen master and the loop in its I/O thread, no ROS.

::

    python -m exo_has_bringup.robot_main --interface socketcan --channel can0 \
        --realtime-priority 40 --socket-dir /run/exo_has

(``ros2 run exo_has_bringup robot_loop`` runs the same.) The process binds the loop's end of
the exchange (:mod:`~exo_has_bringup.robot_exchange`, in ``--socket-dir``), prints ``robot loop
ready`` and carries out the lifecycle transitions its bridge
(:mod:`~exo_has_bringup.robot_bridge`, a managed node) asks for, as ros2_control's hardware
components and ros2_canopen's drivers do:

- configure: open the bus and start the CANopen master: every slave booted, its identity and
  objects checked and set, the drives left disabled; the
  :class:`~exo_has_bringup.robot_loop.RobotLoop` becomes the master's ``control``. A device
  that does not answer, a wrong identity or a drive in fault refuses the transition with a
  message naming it, and the bus is closed again;
- activate: the loop enables the drives (refused, naming the drives' states, when they do not
  all reach operation enabled in time, or under a latched stop) and follows the reference;
- deactivate: every joint holds where it stands, under control, references ignored;
- cleanup: every drive stopped (quick stop, then disable voltage), the I/O thread ended and the
  bus released.

``--activate`` configures and activates at start without a bridge (and exits with 1 if that
fails). While configured the master's I/O thread runs the loop at ``--rate``; the main thread
only carries out a cleanup and waits for a signal. The process imports no rclpy and no DDS:
its only threads are those two (OpenBLAS is kept to the calling thread), and no logging, no
executor and no other thread holds the interpreter lock the loop needs. With
``--realtime-priority N`` both run under SCHED_FIFO (the I/O thread inherits it; it needs root,
CAP_SYS_NICE or an ``rtprio`` limit: ``ulimit -r``); without the permission the process says so
on stderr and runs under the default scheduler. Root refused too is in a control group without a
real-time budget, and the warning names the group and the fix
(:func:`exo_has_common.realtime.set_realtime_priority`). Its memory is locked in RAM at start
(``--lock-memory``, on by default: ``mlockall``, the C heap never trimmed;
:func:`exo_has_common.realtime.lock_memory`), so that no page faults inside a cycle: about 300
MB resident where it would use 110 (every page of the libraries it maps, numpy's and scipy's
among them; ``bench/robot_loop_alone.py``). It needs root, CAP_IPC_LOCK or a ``memlock`` limit
(``ulimit -l``); without, the process says so and runs. Once configured, what it built is kept
from the garbage collector (``gc.freeze``), so a collection walks only what the loop makes.

SIGINT and SIGTERM stop every drive, end the I/O thread, close the sockets and the bus, print
the loop's timing (``robot loop stopped: ...``) and exit with 0. Exit status 1: with
``--activate``, the bus or the devices failed at the start (the message names the device or
object); or the master's I/O thread ended (the bus failed for good); 2: bad arguments.
"""

from __future__ import annotations

import os

# Before numpy is imported: OpenBLAS would start a thread a core, each with its own C heap
# (64 MB reserved) that locking the memory would make resident, for nothing: the loop's
# arithmetic is scalar.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse
import gc
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import can

from exo_has_bringup.errors import BringupError
from exo_has_bringup.robot_exchange import DatagramExchange, default_directory, loop_end
from exo_has_bringup.robot_loop import LoopSettings, RobotLoop
from exo_has_bringup.robot_messages import (
    LifecycleRequest,
    LoopMode,
    LoopState,
    Message,
    Transition,
)
from exo_has_common.errors import ExoHasError
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.realtime import (
    MAX_PRIORITY,
    lock_memory,
    parse_cpus,
    set_cpus,
    set_realtime_priority,
)
from exo_has_common.stopping import StopRequest, stop_on_signals
from exo_has_driver import can_dictionary as cd
from exo_has_driver.hardware.bus import open_bus
from exo_has_driver.hardware.config import JointConfig, MasterConfig
from exo_has_driver.hardware.master import Master
from exo_has_driver.safety_limits import DEFAULT_STARTUP_GRACE
from exo_has_sim.parameters import load_parameters

#: The interpreter's thread switch interval [s]: the main thread, woken by a signal, gives the
#: interpreter lock back within this (Python's default, 5 ms, is a whole period at 200 Hz).
SWITCH_INTERVAL = 5e-4
#: How often the main thread looks at the I/O thread, a cleanup and, while unconfigured, the
#: bridge's requests [s].
POLL_PERIOD = 0.02


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='python -m exo_has_bringup.robot_main', description=__doc__.split('\n', 1)[0])
    parser.add_argument('--interface', default='socketcan',
                        help='python-can interface: socketcan (robot), udp_multicast (simulated '
                             'devices), virtual (default: %(default)s)')
    parser.add_argument('--channel', default='can0',
                        help='CAN channel: can0, or a multicast group (default: %(default)s)')
    parser.add_argument('--bitrate', type=int, default=1_000_000,
                        help='bit rate [bit/s], for interfaces that set it (default: %(default)s)')
    parser.add_argument('--joints', nargs='+', default=list(JOINT_NAMES), metavar='JOINT',
                        help='joints on the bus (default: all four)')
    parser.add_argument('--rate', type=float, default=1.0 / cd.SYNC_PERIOD,
                        help='control and SYNC rate [Hz] (default: %(default)g)')
    parser.add_argument('--hip-params', default='hip',
                        help='hip HAS parameter set: hip or a parameters YAML file')
    parser.add_argument('--knee-params', default='knee',
                        help='knee HAS parameter set: knee or a parameters YAML file')
    parser.add_argument('--stale-periods', type=int, default=LoopSettings.stale_periods,
                        help='periods without a state or a reference after which it is stale '
                             '(default: %(default)s)')
    parser.add_argument('--missed-limit', type=int, default=LoopSettings.missed_limit,
                        help='periods missed in a row that stop every joint (FATAL) '
                             '(default: %(default)s)')
    parser.add_argument('--startup-grace', type=float, default=DEFAULT_STARTUP_GRACE,
                        help='time for the first states, and after a reset before tracking is '
                             'judged [s] (default: %(default)s)')
    parser.add_argument('--socket-dir', type=Path, default=None,
                        help='directory of the sockets shared with the bridge (default: '
                             f'{default_directory()})')
    parser.add_argument('--activate', action='store_true',
                        help='configure and activate at start, without a bridge asking')
    parser.add_argument('--cpus', default='', metavar='LIST',
                        help='CPUs the loop keeps to, as taskset -c takes them (1, 2-3): a core '
                             "of its own, away from ROS's network traffic (default: any)")
    parser.add_argument('--realtime-priority', type=int, default=0, metavar='N',
                        help=f'SCHED_FIFO priority (1 to {MAX_PRIORITY}) of the loop; 0: the '
                             'default scheduler (default: %(default)s)')
    parser.add_argument('--lock-memory', action=argparse.BooleanOptionalAction, default=True,
                        help="lock the process's memory in RAM (mlockall), so that no page "
                             'faults inside a cycle (default: on)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the robot loop until SIGINT or SIGTERM; return the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    unknown = [joint for joint in args.joints if joint not in JOINT_NAMES]
    if unknown or len(set(args.joints)) != len(args.joints):
        parser.error(f'--joints: give distinct joints among {", ".join(JOINT_NAMES)}, got '
                     f'{" ".join(args.joints)}')
    if not 1.0 <= args.rate <= 1000.0:
        parser.error(f'--rate {args.rate:g} Hz must be within 1 and 1000')
    try:
        settings = LoopSettings(period=1.0 / args.rate, stale_periods=args.stale_periods,
                                missed_limit=args.missed_limit,
                                startup_grace=args.startup_grace)
        problem = set_realtime_priority(args.realtime_priority)
        cpus = parse_cpus(args.cpus) if args.cpus else frozenset()
    except ValueError as exc:
        parser.error(str(exc))
    if problem is not None:
        print(f'robot loop: WARNING: --realtime-priority: {problem}', file=sys.stderr,
              flush=True)
    locked = lock_memory() if args.lock_memory else None
    if locked is not None:
        print(f'robot loop: WARNING: --lock-memory: {locked}', file=sys.stderr, flush=True)
    # Before the master's I/O thread exists: it keeps the CPUs of the thread that starts it.
    pinned = set_cpus(cpus)
    if pinned is not None:
        print(f'robot loop: WARNING: --cpus: {pinned}', file=sys.stderr, flush=True)
    sys.setswitchinterval(SWITCH_INTERVAL)
    stop = stop_on_signals()
    try:
        return _run(args, settings, realtime=args.realtime_priority > 0 and problem is None,
                    stop=stop)
    except ExoHasError as exc:
        print(f'robot loop: {exc}', file=sys.stderr, flush=True)
        return 1


class RobotSide:
    """The bus, the master and the loop of one configuration, made and released on request."""

    def __init__(self, args: argparse.Namespace, settings: LoopSettings, realtime: bool,
                 exchange: DatagramExchange) -> None:
        sources = {'hip': args.hip_params, 'knee': args.knee_params}
        params = {joint: load_parameters(sources[joint_type_of(joint)]) for joint in args.joints}
        for joint, p in params.items():
            if p.joint_type != joint_type_of(joint):
                msg = f'{joint}: the parameter set {sources[joint_type_of(joint)]} is a ' \
                      f'{p.joint_type} set'
                raise BringupError(msg)
        self.params = params
        self.config = MasterConfig(tuple(JointConfig.from_parameters(joint, p)
                                         for joint, p in params.items()),
                                   period=settings.period, bitrate=args.bitrate,
                                   enable_timeout=settings.enable_timeout)
        self.args = args
        self.settings = settings
        self.realtime = realtime
        self.exchange = exchange
        self.master: Master | None = None
        self.loop: RobotLoop | None = None
        self._bus: can.BusABC | None = None

    def configure(self, enable: bool) -> None:
        """Open the bus, start the master (the drives enabled or not) and the loop in it.

        Raises
        ------
        ExoHasError
            If the bus cannot be opened or a device fails its start; the message names it.
            The bus is closed again.

        """
        args = self.args
        bus = open_bus(args.interface, args.channel, args.bitrate)
        master = Master(bus, self.config)
        try:
            master.start(enable=enable)
            loop = RobotLoop(master, self.exchange, self.params, self.settings,
                             time.monotonic(), realtime=self.realtime, active=enable)
        except BaseException:
            master.close()
            bus.shutdown()
            raise
        master.take_samples()  # those of the start-up: the loop begins with the next SYNC's
        master.control = loop.cycle
        self._bus, self.master, self.loop = bus, master, loop
        gc.freeze()  # what start-up made stays out of every collection the loop runs into

    def cleanup(self) -> str:
        """Stop every drive, end the I/O thread, close the bus; return the loop's summary."""
        summary = self.loop.summary() if self.loop is not None else ''
        if self.master is not None:
            self.master.close()
        if self._bus is not None:
            self._bus.shutdown()
        self._bus = self.master = self.loop = None
        gc.unfreeze()
        return summary

    def describe(self) -> str:
        """Say what runs, where and how."""
        args = self.args
        scheduler = f'SCHED_FIFO {args.realtime_priority}' if self.realtime \
            else 'default scheduler'
        if args.cpus:
            scheduler += f' on CPUs {args.cpus}'
        return (f'{", ".join(self.params)} on {args.interface}:{args.channel} at '
                f'{1.0 / self.settings.period:g} Hz under {scheduler}, sockets in '
                f'{self.exchange.own.parent}')

    def take_unconfigured(self, message: Message) -> None:
        """Carry out a lifecycle request that came while unconfigured; answer it."""
        if not isinstance(message, LifecycleRequest):
            return  # references, gains and resets wait for a configured loop
        send = self.exchange.send
        if message.transition is Transition.CONFIGURE:
            try:
                self.configure(enable=False)
            except ExoHasError as exc:
                print(f'robot loop: configure refused: {exc}', file=sys.stderr, flush=True)
                send(LoopState(LoopMode.UNCONFIGURED, message.request, False, str(exc)))
                return
            print(f'robot loop configured: {self.describe()}; drives disabled', flush=True)
            send(LoopState(LoopMode.INACTIVE, message.request, True))
        elif message.transition is Transition.CLEANUP:
            send(LoopState(LoopMode.UNCONFIGURED, message.request, True))
        else:
            send(LoopState(LoopMode.UNCONFIGURED, message.request, False,
                           f'the loop is not configured: {message.transition.name.lower()} '
                           'needs a configure first'))


def _run(args: argparse.Namespace, settings: LoopSettings, realtime: bool,
         stop: StopRequest) -> int:
    exchange = loop_end(args.socket_dir or default_directory())
    try:
        side = RobotSide(args, settings, realtime, exchange)
    except BaseException:
        exchange.close()
        raise
    try:
        if args.activate:
            side.configure(enable=True)
            print(f'robot loop ready: active: {side.describe()}', flush=True)
        else:
            print(f'robot loop ready: unconfigured, waiting for its bridge: {side.describe()}',
                  flush=True)
        status = 0
        report_due = 0.0
        while not stop.wait(POLL_PERIOD):
            master, loop = side.master, side.loop
            if master is None or loop is None:
                for message in exchange.receive():
                    side.take_unconfigured(message)
                now = time.monotonic()
                if now >= report_due:  # the loop's own report, while it has no I/O thread
                    exchange.send(LoopState(LoopMode.UNCONFIGURED, 0, True))
                    report_due = now + settings.metrics_period
            elif not master.running:
                print(f'robot loop: FATAL: the CAN master stopped: {master.failure}',
                      file=sys.stderr, flush=True)
                status = 1
                break
            elif loop.cleanup_request:
                request = loop.cleanup_request
                print(f'robot loop cleaned up: {side.cleanup()}', flush=True)
                exchange.send(LoopState(LoopMode.UNCONFIGURED, request, True))
        summary = side.cleanup()
        print(f'robot loop stopped: {summary or "never configured"}', flush=True)
        return status
    finally:
        side.cleanup()
        exchange.close()


if __name__ == '__main__':
    sys.exit(main())

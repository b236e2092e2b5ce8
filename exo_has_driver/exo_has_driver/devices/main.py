"""``can_devices``: the simulated HAS hardware (drives, sensor boards, plants) as a process.

Runs a :class:`~exo_has_driver.devices.rig.Rig` on a python-can bus until SIGINT or SIGTERM::

    can_devices --interface udp_multicast --channel 239.74.163.2 --joints left_hip left_knee

prints ``can devices ready`` once every device has sent its boot-up message, and reads fault
injections from stdin, one command per line (blank lines and ``#`` comments are skipped). Each
line is answered on stdout with ``ok: ...`` or ``error: ...``; a bad line never stops the
process. ``<joint>`` is a joint name, or ``all`` where marked [all]; numbers take Python
syntax (``0x2310``, ``1e6``, ``nan``):

``fault <joint> <code>`` [all]
    The drive faults with CiA 301 error code ``code``: EMCY, 603Fh, *fault*, motor disabled.
    The driver's fault reset (controlword bit 7) clears it.
``heartbeat <joint> off|on [drive|sensor|both]`` [all]
    Stop or resume a device's heartbeat (the drive's unless named).
``sensor <joint> <channel> <value>|nan|clear``
    The sensor board reports ``value`` on ``channel`` (``position`` [m from the retracted
    end], ``pressure_a``/``pressure_b`` [Pa gauge], ``velocity`` [m/s]) instead of the plant's
    reading, saturated at the channel's range; ``nan`` sends the no-reading sentinel and the
    channel's status bit; ``clear`` returns to the plant.
``silence <joint> [on|off]`` [all]
    The joint's devices neither send nor receive any frame (a cut cable); their timers run
    on, so a silenced drive acts on the lost master heartbeat per its 6007h (the driver's
    quick stop, or the default fault 8130h).
``load <joint> <newtons>|default`` [all]
    External rod force [N], positive pushing the cylinder in.
``clear <joint>`` [all]
    Heartbeats on, sensor overrides off, silence off, default load (a drive fault stays).
``status``
    One line per device.
``help``
    This list.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
import threading
from collections.abc import Sequence

from exo_has_common.realtime import MAX_PRIORITY, parse_cpus, set_cpus, set_realtime_priority
from exo_has_common.stopping import stop_on_signals
from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.rig import DEFAULT_LOAD_MASS, Rig
from exo_has_driver.errors import DriverError, FaultInjectionError
from exo_has_driver.hardware.bus import open_bus
from exo_has_sim.errors import SimError

_COMMANDS = ('fault', 'heartbeat', 'sensor', 'silence', 'load', 'clear', 'status', 'help')


def _number(text: str, what: str) -> float:
    try:
        return float(int(text, 0)) if text.lower().startswith('0x') else float(text)
    except ValueError:
        msg = f'{what} must be a number, got {text!r}'
        raise FaultInjectionError(msg) from None


def _arguments(words: list[str], low: int, high: int, usage: str) -> None:
    if not low <= len(words) - 1 <= high:
        msg = f'usage: {usage}'
        raise FaultInjectionError(msg)


def execute(rig: Rig, line: str) -> str:
    """Carry out one stdin command on ``rig``; return the reply (without ``ok:``).

    Raises
    ------
    FaultInjectionError
        For an unknown command, a wrong number of words, an unknown joint, device or
        channel, or a bad number; the message says which.

    """
    words = line.split()
    if not words:
        return ''
    command = words[0].lower()
    if command == 'help':
        return 'commands: ' + ', '.join(_COMMANDS) + ' (see python -m pydoc ' + __name__ + ')'
    if command == 'status':
        return '\n'.join(rig.status())
    if command not in _COMMANDS:
        msg = f'unknown command {command!r}: expected one of {", ".join(_COMMANDS)}'
        raise FaultInjectionError(msg)
    if len(words) < 2:
        msg = f'{command}: a joint (or all) is needed'
        raise FaultInjectionError(msg)
    joint = words[1]
    if joint != 'all':
        rig.joint(joint)  # raises for an unknown joint
    if command == 'fault':
        _arguments(words, 2, 2, 'fault <joint> <code>')
        code = _number(words[2], 'error code')
        if not code.is_integer():
            msg = f'error code must be an integer, got {words[2]!r}'
            raise FaultInjectionError(msg)
        rig.drive_fault(joint, int(code))
        return f'{joint} drive fault 0x{int(code):04X}'
    if command == 'heartbeat':
        _arguments(words, 2, 3, 'heartbeat <joint> off|on [drive|sensor|both]')
        if words[2] not in ('on', 'off'):
            msg = f'heartbeat: expected on or off, got {words[2]!r}'
            raise FaultInjectionError(msg)
        device = words[3] if len(words) > 3 else 'drive'
        rig.set_heartbeat(joint, words[2] == 'on', device)
        return f'{joint} {device} heartbeat {words[2]}'
    if command == 'sensor':
        _arguments(words, 3, 3, 'sensor <joint> <channel> <value>|nan|clear')
        if joint == 'all':
            msg = 'sensor: name one joint'
            raise FaultInjectionError(msg)
        value = None if words[3] == 'clear' else _number(words[3], 'sensor value')
        rig.set_sensor(joint, words[2], value)
        return f'{joint} {words[2]} ' + ('cleared' if value is None else f'reads {value:g}')
    if command == 'silence':
        _arguments(words, 1, 2, 'silence <joint> [on|off]')
        state = words[2] if len(words) > 2 else 'on'
        if state not in ('on', 'off'):
            msg = f'silence: expected on or off, got {state!r}'
            raise FaultInjectionError(msg)
        rig.set_silent(joint, state == 'on')
        return f'{joint} silence {state}'
    if command == 'load':
        _arguments(words, 2, 2, 'load <joint> <newtons>|default')
        force = None if words[2] == 'default' else _number(words[2], 'load force')
        rig.set_load(joint, force)
        return f'{joint} load ' + ('default' if force is None else f'{force:g} N')
    _arguments(words, 1, 1, 'clear <joint>')
    rig.clear(joint)
    return f'{joint} cleared'


def _serve_stdin(rig: Rig, lock: threading.Lock) -> None:
    for raw in sys.stdin:
        line = raw.split('#', 1)[0].strip()
        if not line:
            continue
        try:
            reply = 'ok: ' + execute(rig, line)
        except DriverError as error:
            reply = f'error: {error}'
        except Exception as error:  # a bad line must not end the process
            reply = f'error: {line!r} failed: {type(error).__name__}: {error}'
        with lock, contextlib.suppress(BrokenPipeError):
            print(reply, flush=True)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='can_devices', description=__doc__.split('\n', 1)[0],
        epilog='Fault injection on stdin: see python -m pydoc exo_has_driver.devices.main')
    parser.add_argument('--interface', default='udp_multicast',
                        help='python-can interface: udp_multicast, socketcan, virtual '
                             '(default: %(default)s)')
    parser.add_argument('--channel', default='239.74.163.2',
                        help='bus channel: a multicast group, can0, ... (default: %(default)s)')
    parser.add_argument('--joints', nargs='+', default=list(cd.DRIVE_NODE_IDS),
                        metavar='JOINT', help='joints to simulate (default: all four)')
    parser.add_argument('--load-mass-hip', type=float, default=DEFAULT_LOAD_MASS['hip'],
                        help='carried mass [kg] the default load of the hips is derived for '
                             '(default: %(default)s)')
    parser.add_argument('--load-mass-knee', type=float, default=DEFAULT_LOAD_MASS['knee'],
                        help='carried mass [kg] the default load of the knees is derived for '
                             '(default: %(default)s)')
    parser.add_argument('--initial-angle', type=float, default=0.0,
                        help='joint angle at the start [rad], flexion positive '
                             '(default: %(default)s, standing)')
    parser.add_argument('--tick', type=float, default=cd.SYNC_PERIOD,
                        help='timer period [s]: heartbeats, and advancing the plants when no '
                             'SYNC comes (default: %(default)s)')
    parser.add_argument('--realtime-priority', type=int, default=0, metavar='N',
                        help=f'SCHED_FIFO priority (1 to {MAX_PRIORITY}) of the threads that run '
                             'the devices, as the drives and boards run on microcontrollers of '
                             'their own; 0: the default scheduler (default: %(default)s)')
    parser.add_argument('--cpus', default='', metavar='LIST',
                        help='CPUs the devices keep to, as taskset -c takes them (1, 2-3); '
                             'default: any')
    parser.add_argument('--log-level', default='INFO',
                        choices=['DEBUG', 'INFO', 'WARNING', 'ERROR'])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulated devices until SIGINT or SIGTERM; return the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level, stream=sys.stderr,
                        format='[can_devices] %(levelname)s %(message)s')
    unknown = [j for j in args.joints if j not in cd.DRIVE_NODE_IDS]
    if unknown:
        parser.error(f'unknown joint(s) {", ".join(unknown)}: expected '
                     f'{", ".join(cd.DRIVE_NODE_IDS)}')
    for name in ('load_mass_hip', 'load_mass_knee', 'initial_angle', 'tick'):
        if not math.isfinite(getattr(args, name)):
            parser.error(f'--{name.replace("_", "-")} must be finite')
    # Set before the bus and the rig start their threads, which inherit the scheduling class
    # (numpy's BLAS threads, started at import, stay ordinary: they spin-wait after work).
    try:
        problem = set_realtime_priority(args.realtime_priority)
    except ValueError as error:
        parser.error(f'--realtime-priority: {error}')
    if problem is not None:
        logging.getLogger('can_devices').warning('--realtime-priority: %s', problem)
    try:
        pinned = set_cpus(parse_cpus(args.cpus) if args.cpus else frozenset())
    except ValueError as error:
        parser.error(f'--cpus: {error}')
    if pinned is not None:
        logging.getLogger('can_devices').warning('--cpus: %s', pinned)
    try:
        # The bit rate matters only to interfaces that set it (not SocketCAN, nor simulated).
        bus = open_bus(args.interface, args.channel, 1_000_000)
    except DriverError as error:
        print(f'can_devices: {error}', file=sys.stderr)
        return 2
    stop = stop_on_signals()
    rig: Rig | None = None
    try:
        rig = Rig(bus, args.joints, initial_angle=args.initial_angle, tick=args.tick,
                  load_mass={'hip': args.load_mass_hip, 'knee': args.load_mass_knee})
        rig.start()
        output = threading.Lock()
        with output:
            print(f'can devices ready: {", ".join(args.joints)} on {args.interface}:'
                  f'{args.channel} (drives {[cd.DRIVE_NODE_IDS[j] for j in args.joints]}, '
                  f'sensor boards {[cd.SENSOR_NODE_IDS[j] for j in args.joints]})',
                  flush=True)
        threading.Thread(target=_serve_stdin, args=(rig, output), name='can-devices-stdin',
                         daemon=True).start()
        while not stop.wait(0.2):
            pass
    except (DriverError, SimError) as error:
        print(f'can_devices: {error}', file=sys.stderr)
        return 2
    finally:
        if rig is not None:
            rig.stop()
        bus.shutdown()
    with contextlib.suppress(BrokenPipeError):  # a reader of stdout that went first
        print('can devices stopped', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())

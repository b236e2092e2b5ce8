"""The DDS transport of every exo_has process: Fast DDS over UDP, never its shared memory.

Why. With Jazzy's rmw_fastrtps_cpp (Fast DDS 2.14.5 in the PyPI wheels), a participant that
discovers a reader in another process opens that process's shared-memory port and checks that
the port's listeners answer (``SharedMemGlobal::Port::healthy_check``). If they do not answer at
once, which is common while the other process is starting, the thread sleeps a third of
``healthy_check_timeout_ms``, 333 ms by default, inside ``RTPSParticipantImpl::sendSync``: with
the participant's send lock held. Every publish of the process waits for that lock, and rclpy
publishes with Python's GIL held, so every thread of a node process stands still for 333 ms
each time any process joins the domain (a ``ros2 topic echo``, a recorder, a test's observer):
the plants miss their periods, the controller's commands stop, and the hardware driver's
CANopen master stops sending SYNC and its heartbeat, which the drives take for a lost master
(a FATAL stop). Seen with ``perf`` (the callchains are quoted in bench/README.md, "A process
joining the domain"), and measured by ``bench/joins.py``. Over UDP there is no such port.

What :func:`configure_transport` sets, before a process creates its first participant:

- ``ROS_AUTOMATIC_DISCOVERY_RANGE`` ``SUBNET`` (Jazzy's default), ``SYSTEM_DEFAULT`` or unset:
  ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` unless the variable is set (a user who sets it keeps the
  transports asked for, and is warned if they include shared memory).
- ``LOCALHOST`` (or the deprecated ``ROS_LOCALHOST_ONLY=1``): rmw_fastrtps_cpp adds a
  shared-memory transport whatever is configured (``rmw_fastrtps_shared_cpp/participant.cpp``),
  so the process takes ``SYSTEM_DEFAULT`` instead, with a Fast DDS profile that does what
  LOCALHOST does without the shared memory: no multicast, unicast discovery of the participants
  on 127.0.0.1 (and of ``ROS_STATIC_PEERS``), UDP for the data; and each participant announcing
  itself every :data:`ANNOUNCEMENT_PERIOD` (:func:`localhost_profile` says why).
- A child process inherits all this; given a discovery range of its own (a virtual host's
  ``SUBNET``), it drops the inherited LOCALHOST profile and takes what that range calls for.
- ``OFF``, a profiles file of the user's own (``FASTRTPS_DEFAULT_PROFILES_FILE``), or an RMW
  not on Fast DDS (rmw_cyclonedds_cpp, say): nothing.

``EXO_HAS_DDS_TRANSPORT=rmw`` leaves every setting as rmw_fastrtps_cpp would take it, for the
side-by-side comparison of ``bench/joins.py``. :mod:`exo_has_runtime.test.test_dds` fails if
rmw_fastrtps_cpp stops adding shared memory under LOCALHOST, so the work-around can be reviewed.
ROS-free: it only reads and writes environment variables (and the profile's file).
"""

from __future__ import annotations

import hashlib
import ipaddress
import math
import os
import socket
import tempfile
from collections.abc import Mapping, MutableMapping, Sequence
from pathlib import Path
from xml.etree import ElementTree
from xml.sax.saxutils import escape

from exo_has_runtime.errors import DdsConfigurationError

#: The RMWs on Fast DDS this applies to (the first is Jazzy's default).
FASTRTPS_RMWS = ('rmw_fastrtps_cpp', 'rmw_fastrtps_dynamic_cpp')

#: ``EXO_HAS_DDS_TRANSPORT`` values: ours (the default), or rmw_fastrtps_cpp's as it stands.
TRANSPORT_CHOICES = ('udp', 'rmw')

#: The environment of a process on rmw_fastrtps_cpp's own LOCALHOST settings (shared memory and
#: UDP), whatever this module set in the process that starts it: a third-party participant in
#: tests, and the comparison in the benchmarks.
RMW_LOCALHOST_ENVIRONMENT = {
    'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'FASTRTPS_DEFAULT_PROFILES_FILE': '',
    'FASTDDS_BUILTIN_TRANSPORTS': '', 'EXO_HAS_DDS_TRANSPORT': 'rmw'}

#: How many participants per host unicast discovery tries (rmw_fastrtps_cpp's LOCALHOST value).
MAX_INITIAL_PEERS_RANGE = 32

#: How often a participant on the LOCALHOST profile announces itself [s].
ANNOUNCEMENT_PERIOD = 0.5

#: How often Fast DDS has a participant announce itself unless a profile says otherwise [s].
FAST_DDS_ANNOUNCEMENT_PERIOD = 3.0

#: The XML namespace of Fast DDS's profiles.
PROFILES_NAMESPACE = 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'

#: How the profiles this module writes are named: the prefix, then a hash of the content.
PROFILE_PREFIX = 'exo_has_fastdds_'

#: Fast DDS's names for its built-in transports that include shared memory.
_SHARED_MEMORY_BUILTINS = ('DEFAULT', 'SHM', 'LARGE_DATA')


def configure_transport(environ: MutableMapping[str, str] | None = None) -> str:
    """Keep Fast DDS's shared-memory transport out of this process, before rclpy starts.

    Parameters
    ----------
    environ : MutableMapping[str, str] or None
        The environment to read and change; ``os.environ`` by default (what rcl and Fast DDS
        read when the first participant is created, and what child processes inherit).

    Returns
    -------
    str
        A warning for the process's log when shared memory stays in use by the user's choice,
        else an empty string.

    Raises
    ------
    DdsConfigurationError
        For an unknown ``EXO_HAS_DDS_TRANSPORT``, a static peer that does not resolve, or a
        profile that cannot be written.

    """
    env = os.environ if environ is None else environ
    choice = env.get('EXO_HAS_DDS_TRANSPORT', TRANSPORT_CHOICES[0]).strip().lower()
    if choice not in TRANSPORT_CHOICES:
        msg = (f'EXO_HAS_DDS_TRANSPORT={choice!r}: expected one of '
               f'{", ".join(TRANSPORT_CHOICES)}')
        raise DdsConfigurationError(msg)
    rmw = env.get('RMW_IMPLEMENTATION', '').strip() or FASTRTPS_RMWS[0]
    if choice == 'rmw' or rmw not in FASTRTPS_RMWS:
        return ''
    discovery = discovery_range(env)
    profile = env.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')
    if is_localhost_profile(profile):
        if discovery == 'SYSTEM_DEFAULT':
            return ''  # set up so by this function, in this process or the one that started it
        # Inherited, but this process was given a discovery range of its own (a virtual host's).
        del env['FASTRTPS_DEFAULT_PROFILES_FILE']
    if env.get('FASTRTPS_DEFAULT_PROFILES_FILE'):
        if discovery == 'LOCALHOST':
            return (f'FASTRTPS_DEFAULT_PROFILES_FILE={env["FASTRTPS_DEFAULT_PROFILES_FILE"]} with '
                    'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: rmw_fastrtps_cpp adds shared '
                    'memory, whose port check can stall this process 0.33 s when another '
                    'process joins the domain (exo_has_runtime.dds)')
        return ''
    if discovery == 'OFF':
        return ''
    if discovery == 'LOCALHOST':
        peers = static_peers(env.get('ROS_STATIC_PEERS', ''))
        try:
            written = write_profile(localhost_profile(peers, ANNOUNCEMENT_PERIOD))
        except OSError as exc:
            msg = (f'cannot write the Fast DDS profile for ROS_AUTOMATIC_DISCOVERY_RANGE='
                   f'LOCALHOST into {tempfile.gettempdir()}: {exc}')
            raise DdsConfigurationError(msg) from None
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(written)
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
        env.pop('ROS_LOCALHOST_ONLY', None)
        return ''
    if not env.get('FASTDDS_BUILTIN_TRANSPORTS', '').strip():
        env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'  # empty would be Fast DDS's default
    builtin = env['FASTDDS_BUILTIN_TRANSPORTS']
    if builtin.strip().upper() in _SHARED_MEMORY_BUILTINS:
        return (f'FASTDDS_BUILTIN_TRANSPORTS={builtin} includes shared memory, whose port check '
                'can stall this process 0.33 s when another process joins the domain '
                '(exo_has_runtime.dds); UDPv4 avoids it')
    return ''


def announcement_period(environ: Mapping[str, str] | None = None) -> float:
    """Return how often a participant with this environment announces itself [s].

    What the leaseAnnouncement of the default participant profile in
    ``FASTRTPS_DEFAULT_PROFILES_FILE`` says (:data:`ANNOUNCEMENT_PERIOD` in the one
    :func:`configure_transport` writes), else Fast DDS's 3 s: also where the file cannot be
    read or parsed, which Fast DDS reports itself. A newcomer to the domain that misses its
    first exchange with a participant waits that long for the next.
    """
    env = os.environ if environ is None else environ
    path = env.get('FASTRTPS_DEFAULT_PROFILES_FILE', '').strip()
    if not path:
        return FAST_DDS_ANNOUNCEMENT_PERIOD
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return FAST_DDS_ANNOUNCEMENT_PERIOD
    for participant in root.iter(f'{{{PROFILES_NAMESPACE}}}participant'):
        if participant.get('is_default_profile') != 'true':
            continue
        period = participant.find(f'.//{{{PROFILES_NAMESPACE}}}leaseAnnouncement')
        if period is None:
            break
        seconds = period.findtext(f'{{{PROFILES_NAMESPACE}}}sec', '0')
        nanoseconds = period.findtext(f'{{{PROFILES_NAMESPACE}}}nanosec', '0')
        try:
            return int(seconds) + int(nanoseconds) * 1e-9
        except ValueError:
            break
    return FAST_DDS_ANNOUNCEMENT_PERIOD


def discovery_range(environ: MutableMapping[str, str]) -> str:
    """Return the automatic discovery range rcl will take from an environment, in capitals.

    ``ROS_AUTOMATIC_DISCOVERY_RANGE`` when set, else ``LOCALHOST`` if the deprecated
    ``ROS_LOCALHOST_ONLY`` is 1, else ``SUBNET`` (Jazzy's default).
    """
    value = environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper()
    if value:
        return value
    return 'LOCALHOST' if environ.get('ROS_LOCALHOST_ONLY', '').strip() == '1' else 'SUBNET'


def static_peers(text: str) -> list[str]:
    """Return the IPv4 addresses of ``ROS_STATIC_PEERS`` (``;``-separated names or addresses).

    Raises
    ------
    DdsConfigurationError
        For a peer whose name does not resolve to an IPv4 address (rmw_fastrtps_cpp too takes
        the first IPv4 address of each).

    """
    addresses = []
    for peer in (p.strip() for p in text.split(';')):
        if not peer:
            continue
        try:
            addresses.append(str(ipaddress.IPv4Address(peer)))
        except ValueError:
            try:
                addresses.append(socket.gethostbyname(peer))
            except OSError as exc:
                msg = f'ROS_STATIC_PEERS: cannot resolve {peer!r} to an IPv4 address: {exc}'
                raise DdsConfigurationError(msg) from None
    return addresses


def localhost_profile(peers: Sequence[str] = (),
                      announcement_period: float | None = ANNOUNCEMENT_PERIOD) -> str:
    """Return a Fast DDS XML profile: LOCALHOST discovery over UDP alone.

    What rmw_fastrtps_cpp sets for LOCALHOST, less its shared-memory transport: no built-in
    transports, one UDPv4 transport trying :data:`MAX_INITIAL_PEERS_RANGE` participants per
    host, a unicast metatraffic locator (so no multicast one), and 127.0.0.1 with ``peers`` as
    the initial peers. ``announcement_period`` [s]: how often a participant announces itself
    (None: Fast DDS's 3 s). On this profile one join in four to one in three misses its first
    exchange with a participant (neither a loopback-only interface nor more initial
    announcements changed that) and waits for that participant's next announcement: with 3 s,
    up to 2.9 s, and a session's bring-up took 4.0 to 5.1 s; with 0.5 s, 0.42 s at most and
    2.5 to 2.7 s, the nodes stalling no more often (``bench/discovery.py``,
    ``bench/stalls.py``; bench/README.md, "Discovery").
    """
    announcing = ''
    if announcement_period is not None:
        seconds = math.floor(announcement_period)
        nanoseconds = round((announcement_period - seconds) * 1e9)
        announcing = ('        <discovery_config><leaseAnnouncement>'
                      f'<sec>{seconds}</sec><nanosec>{nanoseconds}</nanosec>'
                      '</leaseAnnouncement></discovery_config>\n')
    locators = ''.join(
        f'<locator><udpv4><address>{escape(address)}</address></udpv4></locator>'
        for address in ('127.0.0.1', *peers))
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<!-- Written by exo_has_runtime.dds: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST without '
        "Fast DDS's shared memory. -->\n"
        f'<profiles xmlns="{PROFILES_NAMESPACE}">\n'
        '  <transport_descriptors>\n'
        '    <transport_descriptor>\n'
        '      <transport_id>exo_has_udp</transport_id>\n'
        '      <type>UDPv4</type>\n'
        f'      <maxInitialPeersRange>{MAX_INITIAL_PEERS_RANGE}</maxInitialPeersRange>\n'
        '    </transport_descriptor>\n'
        '  </transport_descriptors>\n'
        '  <participant profile_name="exo_has_localhost" is_default_profile="true">\n'
        '    <rtps>\n'
        '      <useBuiltinTransports>false</useBuiltinTransports>\n'
        '      <userTransports><transport_id>exo_has_udp</transport_id></userTransports>\n'
        '      <builtin>\n'
        f'{announcing}'
        '        <metatrafficUnicastLocatorList><locator/></metatrafficUnicastLocatorList>\n'
        f'        <initialPeersList>{locators}</initialPeersList>\n'
        '      </builtin>\n'
        '    </rtps>\n'
        '  </participant>\n'
        '</profiles>\n')


def is_localhost_profile(path: str) -> bool:
    """Whether a profiles file is one that :func:`write_profile` wrote."""
    return Path(path).name.startswith(PROFILE_PREFIX) and path.endswith('.xml')


def write_profile(text: str, folder: Path | None = None) -> Path:
    """Write a profile once, named by its content, and return its path.

    Named by a hash of the text, so that every process with the same settings shares one file
    and a child process finds its parent's still there; written to a temporary name first and
    renamed, so that a reader never sees half of it.
    """
    folder = Path(tempfile.gettempdir()) if folder is None else folder
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = folder / f'{PROFILE_PREFIX}{digest}.xml'
    if not path.is_file() or path.read_text(encoding='utf-8') != text:
        partial = path.with_name(f'{path.name}.{os.getpid()}.tmp')
        partial.write_text(text, encoding='utf-8')
        partial.replace(path)
    return path

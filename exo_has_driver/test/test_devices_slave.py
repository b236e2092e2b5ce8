"""CiA 301 services of the simulated devices: boot-up, NMT, heartbeats, SDO, PDO configuration.

Also home of the small test master (python-can and canopen's SDO client on a virtual bus) the
other test_devices_* files import.
"""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Callable, Iterator

import can
import canopen
import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices import Rig
from exo_has_driver.devices.drive import DRIVE_EDS
from exo_has_driver.devices.sensor_board import SENSOR_BOARD_EDS
from exo_has_driver.hardware.cia402 import decode_state
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters

TIMEOUT = 5.0  # s: generous, the machine is shared


class FakeClock:
    """A clock the test moves by hand [s]."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        """Return the time [s]."""
        return self.now


class Master(can.Listener):
    """A minimal CANopen master: raw frames in and out, and canopen's SDO client."""

    def __init__(self, channel: str) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self._condition = threading.Condition()
        self.network = canopen.Network(can.Bus(interface='virtual', channel=channel))
        self.network.NOTIFIER_CYCLE = 0.1  # quicker teardown
        self.network.listeners.append(self)
        self.network.connect()
        self.nodes: dict[int, canopen.RemoteNode] = {}

    def on_message_received(self, msg: can.Message) -> None:
        """Keep every received frame."""
        with self._condition:
            self.frames.append((msg.arbitration_id, bytes(msg.data)))
            self._condition.notify_all()

    def node(self, node_id: int) -> canopen.RemoteNode:
        """Return the canopen node (SDO client) of ``node_id``."""
        if node_id not in self.nodes:
            eds = DRIVE_EDS if node_id < 16 else SENSOR_BOARD_EDS
            node = canopen.RemoteNode(node_id, str(eds))
            node.sdo.RESPONSE_TIMEOUT = TIMEOUT
            self.network.add_node(node)
            self.nodes[node_id] = node
        return self.nodes[node_id]

    def send(self, cob_id: int, data: bytes = b'') -> None:
        """Send one frame."""
        self.network.send_message(cob_id, data)

    def nmt(self, command: int, node_id: int = 0) -> None:
        """Send an NMT command."""
        self.send(0, bytes((command, node_id)))

    def heartbeat(self) -> None:
        """Send the master's heartbeat (operational)."""
        self.send(cd.HEARTBEAT_BASE + cd.MASTER_NODE_ID, b'\x05')

    def clear(self) -> None:
        """Forget the frames received so far."""
        with self._condition:
            self.frames.clear()

    def wait_for(self, cob_id: int, count: int = 1, timeout: float = TIMEOUT,
                 where: Callable[[bytes], bool] = lambda data: True) -> list[bytes]:
        """Wait until ``count`` frames of ``cob_id`` (matching ``where``) came; return them."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while True:
                found = [d for c, d in self.frames if c == cob_id and where(d)]
                if len(found) >= count:
                    return found
                left = deadline - time.monotonic()
                if left <= 0.0:
                    msg = f'{len(found)} of {count} frames 0x{cob_id:03X} within {timeout} s'
                    raise AssertionError(msg)
                self._condition.wait(left)

    def sync(self, clock: FakeClock | None = None, step: float = cd.SYNC_PERIOD,
             expect: tuple[int, ...] = ()) -> list[bytes]:
        """Move the fake clock, send SYNC, wait for the TPDOs ``expect``; return the last ones."""
        before = {cob: len([1 for c, _ in self.frames if c == cob]) for cob in expect}
        if clock is not None:
            clock.now += step
        self.send(cd.SYNC_COB_ID)
        return [self.wait_for(cob, before[cob] + 1)[-1] for cob in expect]

    def close(self) -> None:
        """Disconnect from the bus."""
        self.network.disconnect()


def statusword_of(data: bytes) -> int:
    return int(cd.DRIVE_TPDO1.unpack(data)[0])


@pytest.fixture(name='bench')
def _bench() -> Iterator[tuple[Rig, Master, FakeClock]]:
    """Yield a rig of the left hip on a fresh virtual bus, a master, and the rig's fake clock.

    The hip starts at mid-stroke (21 deg of flexion), so that a drive test has room to move
    either way: standing it is 8 mm from the extended end of its 40 mm stroke.
    """
    hip = load_parameters('hip')
    mid_stroke = float(Linkage.from_parameters(hip).angle(hip.stroke / 2.0))
    channel = f'devices-{uuid.uuid4().hex}'
    bus = can.Bus(interface='virtual', channel=channel)
    master = Master(channel)
    clock = FakeClock()
    rig = Rig(bus, ['left_hip'], clock=clock, initial_angle=mid_stroke)
    rig.start()
    try:
        yield rig, master, clock
    finally:
        rig.stop()
        master.close()
        bus.shutdown()


@pytest.fixture(name='live_bench')
def _live_bench() -> Iterator[tuple[Rig, Master]]:
    """Yield a rig of the left hip and right knee on the wall clock, and a master."""
    channel = f'devices-{uuid.uuid4().hex}'
    bus = can.Bus(interface='virtual', channel=channel)
    master = Master(channel)
    rig = Rig(bus, ['left_hip', 'right_knee'])
    rig.start()
    try:
        yield rig, master
    finally:
        rig.stop()
        master.close()
        bus.shutdown()


def test_every_device_sends_a_boot_up_then_heartbeats_in_pre_operational(
        live_bench: tuple[Rig, Master]) -> None:
    _, master = live_bench
    for node_id in (1, 4, 17, 20):
        assert master.wait_for(cd.HEARTBEAT_BASE + node_id)[0] == b'\x00'
        beats = master.wait_for(cd.HEARTBEAT_BASE + node_id, 3)
        assert beats[1:3] == [b'\x7f', b'\x7f']
    assert not [c for c, _ in master.frames if c in (0x702, 0x703, 0x712, 0x713)]


def test_nmt_start_stop_and_reset_node_change_the_state_the_heartbeat_reports(
        live_bench: tuple[Rig, Master]) -> None:
    rig, master = live_bench
    drive = master.node(1)
    drive.sdo[cd.PROFILE_ACCELERATION].raw = 12345
    master.nmt(0x01, 1)
    master.wait_for(0x701, where=lambda d: d == b'\x05')
    assert rig.joints['right_knee'].drive.nmt_state == 0x7F  # addressed to node 1 only
    master.nmt(0x02)  # all nodes
    master.wait_for(0x714, where=lambda d: d == b'\x04')
    master.wait_for(0x701, where=lambda d: d == b'\x04')
    with pytest.raises(canopen.SdoCommunicationError):
        drive.sdo.RESPONSE_TIMEOUT = 0.3
        drive.sdo[cd.STATUSWORD].raw  # noqa: B018 (no SDO in stopped)
    drive.sdo.RESPONSE_TIMEOUT = TIMEOUT
    master.clear()
    master.nmt(0x81, 1)
    # A stopped heartbeat may still slip in between clear() and the reset: look for these.
    master.wait_for(0x701, where=lambda d: d == b'\x00')  # the boot-up
    master.wait_for(0x701, where=lambda d: d == b'\x7f')  # then pre-operational
    assert drive.sdo[cd.PROFILE_ACCELERATION].raw == 100_000_000  # the EDS default again
    assert not [d for c, d in master.frames if c == 0x714 and d == b'\x00']


def test_sdo_reads_the_identity_device_name_and_fixed_pdo_mappings(
        live_bench: tuple[Rig, Master]) -> None:
    _, master = live_bench
    drive, board = master.node(4), master.node(20)
    assert drive.sdo[0x1000].raw == 0x00020192
    assert drive.sdo[0x1018][1].raw == 0xAB
    assert drive.sdo[0x1018][2].raw == 0x1001
    assert board.sdo[0x1018][2].raw == 0x2001
    assert drive.sdo[0x1018][4].raw == 4  # serial number: the node ID
    assert drive.sdo[0x1014].raw == 0x84
    assert drive.sdo[0x1016][1].raw == (127 << 16) + 150
    assert drive.sdo[0x1017].raw == 50
    # 1008h is longer than 4 bytes: a segmented upload.
    assert drive.sdo[0x1008].raw == 'HAS motor drive (simulated COPLEY-like)'
    assert board.sdo.upload(0x1008, 0) == b'HAS sensor board'
    drive.rpdo.read()
    drive.tpdo.read()
    board.tpdo.read()
    def layout(pdo: canopen.pdo.PdoMap) -> tuple[tuple[int, int, int], ...]:
        return tuple((v.index, v.subindex, len(v.od)) for v in pdo.map)
    assert layout(drive.rpdo[1]) == cd.DRIVE_RPDO1_MAP
    assert layout(drive.tpdo[1]) == cd.DRIVE_TPDO1_MAP
    assert layout(board.tpdo[1]) == cd.SENSOR_TPDO1_MAP
    assert layout(board.tpdo[2]) == cd.SENSOR_TPDO2_MAP
    assert drive.tpdo[1].cob_id == 0x184 and drive.tpdo[1].trans_type == 1
    assert board.tpdo[2].cob_id == 0x294 and board.tpdo[2].trans_type == 1


def test_rewriting_the_same_mapping_is_accepted_and_a_different_one_is_aborted(
        live_bench: tuple[Rig, Master]) -> None:
    _, master = live_bench
    drive, board = master.node(1), master.node(17)
    drive.rpdo.read()
    drive.tpdo.read()
    board.tpdo.read()
    drive.rpdo.save()  # invalidates, clears, rewrites and validates the same mapping
    drive.tpdo.save()
    board.tpdo.save()
    assert drive.sdo[0x1600][0].raw == 2
    assert drive.sdo[0x1400][1].raw == 0x201
    cases = [
        (drive, 0x1A00, 1, struct.pack('<I', 0x60410020), 0x06040041),  # another size
        (board, 0x1A01, 3, struct.pack('<I', 0x21000110), 0x06040041),  # another object
        (drive, 0x1600, 0, b'\x05', 0x06090030),  # another count
        (drive, 0x1800, 1, struct.pack('<I', 0x190), 0x06090030),  # another COB-ID
        (drive, 0x1800, 2, b'\xfe', 0x06090030),  # event-driven
        (drive, cd.STATUSWORD, 0, b'\x00\x00', 0x06010002),  # read-only
        (drive, 0x2200, 0, b'\x00\x00', 0x06020000),  # no such object
        (drive, 0x1018, 7, b'\x00', 0x06090011),  # no such sub-index
        (drive, cd.PROFILE_ACCELERATION, 0, b'\x01\x00', 0x06070013),  # too short
        (drive, 0x1005, 0, struct.pack('<I', 0x40000080), 0x06090030),  # SYNC producer
    ]
    for node, index, subindex, data, code in cases:
        with pytest.raises(canopen.SdoAbortedError) as aborted:
            node.sdo.download(index, subindex, data)
        assert aborted.value.code == code, (hex(index), subindex)
    assert drive.sdo[0x1A00][1].raw == 0x60410010


def test_a_segmented_download_is_stored_like_an_expedited_one(
        live_bench: tuple[Rig, Master]) -> None:
    _, master = live_bench
    drive = master.node(1)
    drive.sdo.download(cd.PROFILE_DECELERATION, 0, struct.pack('<I', 7_654_321),
                       force_segment=True)
    assert drive.sdo[cd.PROFILE_DECELERATION].raw == 7_654_321
    drive.sdo.download(0x1017, 0, struct.pack('<H', 20))
    assert drive.sdo[0x1017].raw == 20


def test_pdos_are_exchanged_only_in_nmt_operational(
        bench: tuple[Rig, Master, FakeClock]) -> None:
    rig, master, clock = bench
    master.sync(clock)
    time.sleep(0.1)
    assert not [c for c, _ in master.frames if c in (0x181, 0x191, 0x291)]
    assert rig.syncs == 1
    master.nmt(0x01)
    drive_tpdo, board_tpdo1, board_tpdo2 = master.sync(clock, expect=(0x181, 0x191, 0x291))
    assert decode_state(statusword_of(drive_tpdo)) == 'switch on disabled'
    # The counter counts every SYNC, pre-operational ones too.
    assert cd.SENSOR_TPDO2.unpack(board_tpdo2)[2] == 2
    assert 0 < cd.SENSOR_TPDO1.unpack(board_tpdo1)[0] < 130_000  # um, within the stroke

"""CiA 301 services of the simulated devices: boot-up, NMT, heartbeats, SDO, PDO configuration.

The bench (a small master and a fake clock) is devices_bench.py's, the fixtures conftest.py's.
"""

from __future__ import annotations

import struct
import time

import canopen
import pytest
from devices_bench import TIMEOUT, Bench, LiveBench, statusword_of

from exo_has_driver import can_dictionary as cd
from exo_has_driver.hardware.cia402 import decode_state


def test_every_device_sends_a_boot_up_then_heartbeats_in_pre_operational(
        live_bench: LiveBench) -> None:
    _, master = live_bench
    for node_id in (1, 4, 17, 20):
        assert master.wait_for(cd.HEARTBEAT_BASE + node_id)[0] == b'\x00'
        beats = master.wait_for(cd.HEARTBEAT_BASE + node_id, 3)
        assert beats[1:3] == [b'\x7f', b'\x7f']
    assert not [c for c, _ in master.frames if c in (0x702, 0x703, 0x712, 0x713)]


def test_nmt_start_stop_and_reset_node_change_the_state_the_heartbeat_reports(
        live_bench: LiveBench) -> None:
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
        live_bench: LiveBench) -> None:
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
        live_bench: LiveBench) -> None:
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
        live_bench: LiveBench) -> None:
    _, master = live_bench
    drive = master.node(1)
    drive.sdo.download(cd.PROFILE_DECELERATION, 0, struct.pack('<I', 7_654_321),
                       force_segment=True)
    assert drive.sdo[cd.PROFILE_DECELERATION].raw == 7_654_321
    drive.sdo.download(0x1017, 0, struct.pack('<H', 20))
    assert drive.sdo[0x1017].raw == 20


def test_pdos_are_exchanged_only_in_nmt_operational(
        bench: Bench) -> None:
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

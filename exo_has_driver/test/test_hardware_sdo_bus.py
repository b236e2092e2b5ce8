import struct
import uuid

import can
import pytest

from exo_has_driver.errors import (
    CanBusError,
    CanOpenError,
    CanOpenTimeoutError,
    HardwareConfigError,
)
from exo_has_driver.hardware.bus import (
    bus_state_fault,
    error_frame_fault,
    open_bus,
    random_multicast_group,
)
from exo_has_driver.hardware.sdo import SdoClient


class Server:
    """A minimal SDO server over a dictionary of raw values, answering as a slave would."""

    def __init__(self, values):
        self.values = values
        self.requests = []
        self.pending = b''
        self.toggle = 0

    def __call__(self, node, request, timeout):
        """Answer one request."""
        self.requests.append((node, bytes(request)))
        command, index, sub = struct.unpack_from('<BHB', request)
        if command >> 5 == 3:  # upload segment
            chunk, self.pending = self.pending[:7], self.pending[7:]
            flags = (command & 0x10) | ((7 - len(chunk)) << 1) | (not self.pending)
            return bytes([flags]) + chunk.ljust(7, b'\0')
        if (index, sub) not in self.values:
            return struct.pack('<BHBI', 0x80, index, sub, 0x06020000)
        if command >> 5 == 2:  # initiate upload
            data = self.values[(index, sub)]
            if len(data) <= 4:
                return struct.pack('<BHB', 0x43 | ((4 - len(data)) << 2), index, sub) + \
                    data.ljust(4, b'\0')
            self.pending = data
            return struct.pack('<BHBI', 0x41, index, sub, len(data))
        size = 4 - ((command >> 2) & 3)
        self.values[(index, sub)] = bytes(request[4:4 + size])
        return struct.pack('<BHB', 0x60, index, sub) + bytes(4)


def test_expedited_reads_and_writes_carry_the_object_and_its_size():
    server = Server({(0x1018, 1): b'\xab\0\0\0', (0x6060, 0): b'\x01'})
    sdo = SdoClient(server)
    assert sdo.read_unsigned(5, 0x1018, 1) == 0xAB
    sdo.write_signed(5, 0x6060, 0, -3, 1)
    assert server.requests[-1] == (5, bytes([0x2F, 0x60, 0x60, 0, 0xFD, 0, 0, 0]))
    assert sdo.read_signed(5, 0x6060, 0) == -3
    with pytest.raises(CanOpenError, match='node 5: write 1017h sub 0 aborted'):
        sdo.write_unsigned(5, 0x1017, 0, 50, 2)
    assert server.values[(0x6060, 0)] == b'\xfd'


def test_a_segmented_upload_is_reassembled():
    name = b'HAS motor drive (simulated)'
    sdo = SdoClient(Server({(0x1008, 0): name}))
    assert sdo.upload(3, 0x1008, 0) == name


def test_an_abort_names_node_object_and_reason():
    sdo = SdoClient(Server({}))
    with pytest.raises(CanOpenError, match=r'node 4: read 1018h sub 2 aborted: 0x06020000 '
                                           r'Object does not exist'):
        sdo.read_unsigned(4, 0x1018, 2)


def test_a_silent_node_times_out_naming_node_and_object_after_the_retries():
    asked = []

    def nobody(node, request, timeout):
        asked.append(timeout)

    sdo = SdoClient(nobody, timeout=0.2, retries=2)
    with pytest.raises(CanOpenTimeoutError, match=r'node 20 did not answer the SDO write of '
                                                  r'1017h sub 0 within 0.2 s \(3 tries\)'):
        sdo.write_unsigned(20, 0x1017, 0, 50, 2)
    assert asked == [0.2, 0.2, 0.2]


def test_open_bus_opens_a_virtual_bus_and_explains_what_it_cannot_open():
    bus = open_bus('virtual', f'test-{uuid.uuid4().hex}', 1_000_000)
    bus.shutdown()
    with pytest.raises(CanBusError, match="CAN interface 'no_such_can' is not available"):
        open_bus('no_such_can', 'can0', 1_000_000)
    with pytest.raises(HardwareConfigError, match='channel is empty'):
        open_bus('socketcan', '', 1_000_000)
    with pytest.raises(HardwareConfigError, match='bit rate 0'):
        open_bus('virtual', 'x', 0)


def test_error_frames_of_bus_off_and_error_passive_are_bus_faults():
    def frame(flags, data=bytes(8)):
        return can.Message(arbitration_id=flags, data=data, is_error_frame=True)

    assert 'bus-off' in error_frame_fault(frame(0x0040))
    assert 'error passive' in error_frame_fault(frame(0x0004, bytes([0, 0x20, 0, 0, 0, 0, 0,
                                                                     0])))
    assert error_frame_fault(frame(0x0004, bytes([0, 0x04, 0, 0, 0, 0, 0, 0]))) is None
    assert error_frame_fault(can.Message(arbitration_id=0x40, data=b'')) is None


def test_the_bus_state_is_a_fault_when_passive_or_off():
    class Bus:
        state = can.BusState.ACTIVE

    bus = Bus()
    assert bus_state_fault(bus) is None
    bus.state = can.BusState.PASSIVE
    assert bus_state_fault(bus) == 'the CAN bus is error passive'
    bus.state = can.BusState.ERROR
    assert 'bus-off' in bus_state_fault(bus)


def test_a_late_answer_for_another_object_is_skipped_and_the_wait_goes_on():
    late = struct.pack('<BHB', 0x43, 0x1018, 1) + b'\xab\0\0\0'
    right = struct.pack('<BHB', 0x43, 0x1000, 0) + b'\x92\x01\x02\0'
    answers, requests = [late, right], []

    def exchange(node, request, timeout):
        requests.append(request)
        return answers.pop(0)

    assert SdoClient(exchange).read_unsigned(1, 0x1000, 0) == 0x00020192
    assert requests[1] is None  # waited again without repeating the request


def test_udp_multicast_buses_hear_their_own_group_only():
    group = random_multicast_group()
    other = group.replace('239.74.', '239.75.', 1)  # a different group on the same port
    listener = open_bus('udp_multicast', group, 1_000_000)
    stranger = open_bus('udp_multicast', other, 1_000_000)
    neighbour = open_bus('udp_multicast', group, 1_000_000)
    try:
        stranger.send(can.Message(arbitration_id=0x123, data=b'\x01', is_extended_id=False))
        neighbour.send(can.Message(arbitration_id=0x124, data=b'\x02', is_extended_id=False))
        received = []
        message = listener.recv(2.0)
        while message is not None:
            received.append(message.arbitration_id)
            message = listener.recv(0.2)
        assert received == [0x124]
    finally:
        for bus in (listener, stranger, neighbour):
            bus.shutdown()

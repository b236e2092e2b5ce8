"""The bench of the simulated devices' tests: a small CANopen master and a clock moved by hand.

Not a test module: test_devices_slave, test_devices_drive and test_devices_sensor_board use it,
and conftest.py builds their ``bench`` and ``live_bench`` fixtures from it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import can
import canopen

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices import Rig
from exo_has_driver.devices.drive import DRIVE_EDS
from exo_has_driver.devices.sensor_board import SENSOR_BOARD_EDS

TIMEOUT = 5.0  # s: generous, the machine is shared


class FakeClock:
    """A clock the test moves by hand [s]."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        """Return the time [s]."""
        return self.now


class BenchMaster(can.Listener):
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


#: A rig on a fake clock, its master, and the clock.
Bench = tuple[Rig, BenchMaster, FakeClock]
#: A rig on the wall clock, and its master.
LiveBench = tuple[Rig, BenchMaster]

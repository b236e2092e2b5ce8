"""Fixtures of the simulated devices' tests: a rig of devices on a virtual bus, and a master."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import can
import pytest
from devices_bench import Bench, BenchMaster, FakeClock, LiveBench

from exo_has_driver.devices import Rig
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters


@pytest.fixture(name='bench')
def _bench() -> Iterator[Bench]:
    """Yield a rig of the left hip on a fresh virtual bus, a master, and the rig's fake clock.

    The hip starts at mid-stroke (21 deg of flexion), so that a drive test has room to move
    either way: standing it is 8 mm from the extended end of its 40 mm stroke.
    """
    hip = load_parameters('hip')
    mid_stroke = float(Linkage.from_parameters(hip).angle(hip.stroke / 2.0))
    channel = f'devices-{uuid.uuid4().hex}'
    bus = can.Bus(interface='virtual', channel=channel)
    master = BenchMaster(channel)
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
def _live_bench() -> Iterator[LiveBench]:
    """Yield a rig of the left hip and right knee on the wall clock, and a master."""
    channel = f'devices-{uuid.uuid4().hex}'
    bus = can.Bus(interface='virtual', channel=channel)
    master = BenchMaster(channel)
    rig = Rig(bus, ['left_hip', 'right_knee'])
    rig.start()
    try:
        yield rig, master
    finally:
        rig.stop()
        master.close()
        bus.shutdown()

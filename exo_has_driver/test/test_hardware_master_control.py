"""The master's control hook: a law in the I/O thread, whose commands go out with the SYNC."""

from __future__ import annotations

import threading
import time
import uuid

import can
import pytest

from exo_has_driver.devices.rig import Rig
from exo_has_driver.hardware.config import JointConfig, MasterConfig
from exo_has_driver.hardware.master import Master
from exo_has_sim.parameters import load_parameters


def test_the_control_hook_runs_every_sync_in_the_io_thread_and_its_commands_go_out_with_it():
    channel = f'control-{uuid.uuid4().hex}'
    rig_bus = can.Bus(interface='virtual', channel=channel)
    bus = can.Bus(interface='virtual', channel=channel)
    rig = Rig(rig_bus, ['left_hip'])
    rig.start()
    calls: list[tuple[float, int]] = []
    config = MasterConfig((JointConfig.from_parameters('left_hip', load_parameters('hip')),))

    def control(now: float) -> None:
        calls.append((now, threading.get_native_id()))
        master.set_command('left_hip', -20.0, True, now)

    master = Master(bus, config, control=control)
    try:
        master.start()
        master.take_samples()
        time.sleep(0.3)
        samples = master.take_samples()
        thread = master.io_thread_id
    finally:
        master.close()
        rig.stop()
        bus.shutdown()
        rig_bus.shutdown()
    assert {native for _, native in calls} == {thread}
    # 0.3 s at 200 Hz is 60 SYNCs; the shared machine may lose a few.
    recent = [now for now, _ in calls if now > calls[-1][0] - 0.3]
    assert len(recent) >= 30
    quantum = 1.0 / config.units.velocity_per_rad_s
    assert samples and all(s.motor_speed_command == pytest.approx(-20.0, abs=quantum)
                           for s in samples)

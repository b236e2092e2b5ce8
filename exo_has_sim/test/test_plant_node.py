"""Tests of the plant node as a process: its real-time scheduling class."""

from __future__ import annotations

import os

from exo_has_runtime.testing.processes import NodeProcess


def test_a_plant_asked_for_a_realtime_priority_runs_its_ticks_under_sched_fifo(tmp_path):
    with NodeProcess('exo_has_sim.plant_node', [
            '--ros-args', '-p', 'joint:=left_hip', '-p', 'realtime_priority:=10'],
            log_path=tmp_path / 'plant.log') as plant:
        plant.wait_for_output(r'plant ready', 120.0)
        # The main thread (its ID is the process's) spins the node.
        policy = os.sched_getscheduler(plant.process.pid)
        if 'no permission' in plant.output:
            assert policy == os.SCHED_OTHER
        else:
            assert policy == os.SCHED_FIFO
            assert os.sched_getparam(plant.process.pid).sched_priority == 10
        assert plant.stop() == 0


def test_a_realtime_priority_out_of_range_stops_the_plant_naming_the_parameter(tmp_path):
    with NodeProcess('exo_has_sim.plant_node', [
            '--ros-args', '-p', 'joint:=left_hip', '-p', 'realtime_priority:=99'],
            log_path=tmp_path / 'plant.log') as plant:
        assert plant.wait(timeout_s=60.0) != 0
        assert 'realtime_priority' in plant.output

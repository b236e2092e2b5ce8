"""Tests of the PD controller node as a process: its real-time scheduling class."""

from __future__ import annotations

import os

from exo_has_runtime.testing.processes import NodeProcess


def test_a_controller_asked_for_a_realtime_priority_answers_under_sched_fifo(tmp_path):
    with NodeProcess('exo_has_control.pd_controller', [
            '--ros-args', '-p', 'realtime_priority:=10'],
            log_path=tmp_path / 'controller.log') as controller:
        controller.wait_for_output(r'controller ready', 60.0)
        # The main thread (its ID is the process's) spins the node.
        policy = os.sched_getscheduler(controller.process.pid)
        if 'no permission' in controller.output:
            assert policy == os.SCHED_OTHER
        else:
            assert policy == os.SCHED_FIFO
            assert os.sched_getparam(controller.process.pid).sched_priority == 10
        assert controller.stop() == 0


def test_a_realtime_priority_out_of_range_stops_the_controller_naming_the_parameter(tmp_path):
    with NodeProcess('exo_has_control.pd_controller', [
            '--ros-args', '-p', 'realtime_priority:=99'],
            log_path=tmp_path / 'controller.log') as controller:
        assert controller.wait(timeout_s=60.0) != 0
        assert 'realtime_priority' in controller.output
        assert 'Traceback' not in controller.output

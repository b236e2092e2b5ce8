"""The nodes that answer the control loop's samples take a real-time scheduling class.

The plant and the PD controller each take ``realtime_priority``: SCHED_FIFO for the thread
that spins the node (exo_has_common.realtime); the DDS threads stay ordinary. Without the
right to it (not root, no CAP_SYS_NICE) a node runs under the default scheduler and says so,
which is all these tests can check there; CI runs as root.
"""

from __future__ import annotations

import pytest

from exo_has_runtime.processes import NodeProcess

pytestmark = pytest.mark.process  # every test here starts processes

NODES = {
    'plant': ('exo_has_sim.plant_node', ('-p', 'joint:=left_hip'), r'plant ready'),
    'controller': ('exo_has_control.pd_controller', (), r'controller ready'),
}


@pytest.mark.parametrize('node', NODES)
def test_a_node_asked_for_a_realtime_priority_spins_under_sched_fifo(tmp_path, node):
    module, arguments, ready = NODES[node]
    with NodeProcess(module, ['--ros-args', *arguments, '-p', 'realtime_priority:=10'],
                     log_path=tmp_path / f'{node}.log') as process:
        process.wait_for_output(ready, 120.0)
        # The main thread (its ID is the process's) spins the node.
        assert process.runs_at_realtime_priority(10), process.output
        assert process.stop() == 0


@pytest.mark.parametrize('node', NODES)
def test_a_realtime_priority_out_of_range_stops_the_node_naming_the_parameter(tmp_path, node):
    module, arguments, _ = NODES[node]
    with NodeProcess(module, ['--ros-args', *arguments, '-p', 'realtime_priority:=99'],
                     log_path=tmp_path / f'{node}.log') as process:
        assert process.wait(timeout_s=60.0) != 0
        assert 'realtime_priority' in process.output
        assert 'Traceback' not in process.output

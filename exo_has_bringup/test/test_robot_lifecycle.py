"""The robot side's lifecycle on the simulated devices, asked as ``ros2 lifecycle set`` would.

The devices and the robot loop run on a bus of their own, the bridge with ``autostart`` off;
this test process asks the bridge's transitions over its ``change_state`` service and watches
the states. HasState carries no drive state: a drive that is not in operation enabled shows
as the compact valve in free mode (its motor stopped, exo_has_driver.hardware.config
.infer_valve_mode), one enabled and holding its joint under the devices' load as assist.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator

import pytest
from robot_graph import DISCOVERY_S, Graph

from exo_has_bringup.plan import devices_priority
from exo_has_common.joints import JOINT_NAMES
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_msgs.msg import HasState
from exo_has_runtime.processes import NodeProcess

pytestmark = pytest.mark.process

RATE = 100.0  # Hz, as the CAN session test: devices, loop, bridge and test share two cores
REALTIME_PRIORITY = 20
START_S = 30.0  # fresh interpreters import numpy, scipy and rclpy on a loaded machine


@pytest.fixture
def graph(ros_context: object) -> Iterator[Graph]:
    graph = Graph(ros_context)
    yield graph
    graph.close()


def valves(graph: Graph, mode: int, last: int = 1) -> bool:
    """Whether every joint's ``last`` newest states report the compact valve in ``mode``."""
    return all(graph.states[j] and all(s.valve_mode == mode for s in graph.states[j][-last:])
               for j in JOINT_NAMES)


def test_a_drive_fault_refuses_configure_naming_it_and_the_transitions_follow_the_drives(
        graph: Graph) -> None:
    group = random_multicast_group()
    bus = ['--interface', 'udp_multicast', '--channel', group]
    devices_args = [*bus, '--realtime-priority', f'{devices_priority(REALTIME_PRIORITY)}']
    with tempfile.TemporaryDirectory(prefix='exo-life-') as directory, \
            NodeProcess('exo_has_bringup.robot_main', [
                *bus, '--rate', f'{RATE}', '--socket-dir', directory,
                '--realtime-priority', f'{REALTIME_PRIORITY}']) as loop, \
            NodeProcess('exo_has_bringup.robot_bridge', [
                '--ros-args', '-p', f'socket_dir:={directory}', '-p', f'rate:={RATE}',
                '-p', 'autostart:=false', '-p', 'diagnostics_period:=0.2']) as bridge:
        with NodeProcess('exo_has_driver.devices.main', devices_args, stdin=True) as devices:
            devices.wait_for_output('can devices ready', START_S)
            devices.send('fault left_knee 0x7121')
            devices.wait_for_output('left_knee drive fault 0x7121', START_S)
            loop.wait_for_output('robot loop ready: unconfigured', START_S)
            bridge.wait_for_output('robot bridge ready: unconfigured', START_S)

            # Configure finds the faulted drive: refused, naming it; activate is then refused.
            assert not graph.change_state('configure')
            found = bridge.wait_for_output(r'configure refused by the robot loop: (.*)')
            assert 'left_knee drive (node 2)' in found.group(1), found.group(1)
            assert '0x7121' in found.group(1), found.group(1)
            assert not graph.change_state('activate')
            assert graph.states == {joint: [] for joint in JOINT_NAMES}  # the bus stays closed

        # The drives powered up again without the fault: configure opens the bus, the drives
        # left disabled.
        with NodeProcess('exo_has_driver.devices.main', devices_args) as devices:
            devices.wait_for_output('can devices ready', START_S)
            assert graph.change_state('configure'), bridge.output
            assert graph.run(DISCOVERY_S, lambda: all(graph.states.values()))
            graph.run(0.5)
            assert valves(graph, HasState.VALVE_FREE, last=40)

            # Activate enables them and the joints follow the reference.
            assert graph.change_state('activate'), bridge.output
            assert graph.run(2.0, lambda: valves(graph, HasState.VALVE_ASSIST))
            graph.start_walking()
            assert graph.run(10.0, graph.following), graph.errors_deg()

            # Deactivate holds every joint where it stands, enabled, the reference ignored.
            assert graph.change_state('deactivate'), bridge.output
            graph.run(0.3)  # the joints stop from up to 16 deg/s
            moved = graph.still(1.5)
            assert max(moved.values()) < 0.005, moved  # rad; the swing goes on 0.17 rad wide
            assert valves(graph, HasState.VALVE_ASSIST, last=40)

            # Cleanup stops the drives and releases the bus: no state comes any more.
            assert graph.change_state('cleanup'), bridge.output
            loop.wait_for_output('robot loop cleaned up')
            graph.run(0.5)
            for states in graph.states.values():
                states.clear()
            graph.run(1.0)
            assert graph.states == {joint: [] for joint in JOINT_NAMES}
            assert [e.text for e in graph.events if e.severity >= 3] == []

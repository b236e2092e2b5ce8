"""The robot side as a user runs it: simulated devices, the robot loop, its ROS bridge.

The devices and the loop run on a udp_multicast bus of their own under SCHED_FIFO where
permitted (as in the CAN session test); the bridge is an ordinary rclpy node, and this test
process is the rest of the ROS graph: it publishes a walking-like reference (each joint swings
about where it stood) and the resets, sets the bridge's gains as ``ros2 param set`` does, and
listens to the states, the safety events and ``/diagnostics``.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import tempfile
import time
from collections.abc import Iterator

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import qos_profile_sensor_data
from robot_graph import DISCOVERY_S, FOLLOWING, SWING, SWING_HZ, Graph
from std_msgs.msg import Empty

from exo_has_bringup.plan import devices_priority
from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import has_command_topic
from exo_has_driver.events import SafetyKind, Severity
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_msgs.msg import HasCommand
from exo_has_runtime.processes import NodeProcess

pytestmark = pytest.mark.process

RATE = 100.0  # Hz, as the CAN session test: devices, loop, bridge and test share two cores
STALE_PERIODS = 20  # the loop's reference is stale after 0.2 s without one
REALTIME_PRIORITY = 20
START_S = 30.0  # fresh interpreters import numpy, scipy and rclpy on a loaded machine
#: How far a joint may move once its reference stops coming [rad]: the reference the loop last
#: had, held still after its timeout, is within the swing's rate times the stale time of where
#: the joint stood, and the hold keeps the joint within the tracking error of it.
HELD = SWING * 2.0 * math.pi * SWING_HZ * STALE_PERIODS / RATE + FOLLOWING
#: How long the test stops the loop [s]: a few periods missed, far from the loop's limit of 9
#: in a row (a FATAL stop) even if this process wakes 15 ms late.
STALL_S = 0.03


def described(status: DiagnosticStatus) -> str:
    """Return a status's message and values: the loop's timing when a test fails on it."""
    return f'{status.message}: ' + ', '.join(f'{v.key} {v.value}' for v in status.values)


@pytest.fixture
def graph(ros_context: object) -> Iterator[Graph]:
    graph = Graph(ros_context)
    yield graph
    graph.close()


def test_the_robot_side_takes_gains_holds_through_a_killed_bridge_and_stops_on_a_stray_commander(
        graph: Graph) -> None:
    group = random_multicast_group()
    bus = ['--interface', 'udp_multicast', '--channel', group]
    # The bridges end with the test however it ends (the second replaces the killed first).
    with tempfile.TemporaryDirectory(prefix='exo-bridge-') as directory, \
            contextlib.ExitStack() as bridges, \
            NodeProcess('exo_has_driver.devices.main', [
                *bus, '--realtime-priority', f'{devices_priority(REALTIME_PRIORITY)}']) as devices:
        devices.wait_for_output('can devices ready', START_S)
        with NodeProcess('exo_has_bringup.robot_main', [
                *bus, '--rate', f'{RATE}', '--stale-periods', f'{STALE_PERIODS}',
                '--socket-dir', directory,
                '--realtime-priority', f'{REALTIME_PRIORITY}']) as loop:
            loop.wait_for_output('robot loop ready', START_S)
            args = ['--ros-args', '-p', f'socket_dir:={directory}', '-p', f'rate:={RATE}',
                    '-p', 'diagnostics_period:=0.2']
            bridge = bridges.enter_context(NodeProcess('exo_has_bringup.robot_bridge', args))
            bridge.wait_for_output('robot bridge ready', START_S)
            assert graph.run(DISCOVERY_S, lambda: all(graph.states.values())), bridge.output
            graph.start_walking()
            assert graph.run(10.0, graph.following), \
                (graph.errors_deg(), graph.statuses[-1:],
                 [e.text for e in graph.events])
            graph.run(2.0)
            assert graph.following(), graph.errors_deg()

            # Gains: an unsafe change is refused with its reason; a safe one is taken.
            ok, reason = graph.set_parameters(**{'knee.kp': 5.0e6})
            assert not ok and 'knee gains' in reason and 'damping' in reason, reason
            ok, reason = graph.set_parameters(**{'knee.kp': 30000.0})
            assert ok, reason
            graph.run(1.0)
            assert graph.following(), graph.errors_deg()

            # SIGKILL mid-walk; the reference keeps coming, to nobody.
            bridge.kill()
            killed = {joint: graph.angle(joint) for joint in JOINT_NAMES}
            graph.run(1.0)
            for states in graph.states.values():
                states.clear()
            graph.statuses.clear()
            events_before = len(graph.events)
            bridge = bridges.enter_context(NodeProcess('exo_has_bringup.robot_bridge', args))
            bridge.wait_for_output('robot bridge ready', START_S)

            # The new bridge shows every joint held where it was, and says why.
            assert graph.run(DISCOVERY_S, lambda: all(graph.states.values())
                             and bool(graph.statuses)), bridge.output
            moved = graph.still(1.0)
            assert max(moved.values()) < 0.005, moved  # rad; the swing goes on 0.17 rad wide
            status = graph.statuses[-1]
            assert status.level == DiagnosticStatus.WARN and 'holding' in status.message, \
                status.message
            for joint in JOINT_NAMES:
                assert abs(graph.angle(joint) - killed[joint]) < HELD, \
                    (joint, math.degrees(graph.angle(joint) - killed[joint]))

            # A reset resumes the walk.
            graph.reset.publish(Empty())
            assert graph.run(5.0, lambda: any(e.kind == SafetyKind.RESET
                                              for e in graph.events[events_before:])), \
                [e.text for e in graph.events]
            assert graph.run(10.0, graph.following), \
                graph.errors_deg()
            assert graph.run(3.0, lambda: graph.statuses[-1].level == DiagnosticStatus.OK), \
                described(graph.statuses[-1])

            # A stall of the loop shows in the status of its window, and only there.
            os.kill(loop.process.pid, signal.SIGSTOP)
            time.sleep(STALL_S)
            os.kill(loop.process.pid, signal.SIGCONT)
            assert graph.run(2.0, lambda: 'periods missed in the last'
                             in graph.statuses[-1].message), described(graph.statuses[-1])
            assert graph.statuses[-1].level == DiagnosticStatus.WARN
            assert graph.run(3.0, lambda: graph.statuses[-1].level == DiagnosticStatus.OK), \
                described(graph.statuses[-1])
            assert graph.following(), graph.errors_deg()

            # A stray commander of a joint (a controller left running) stops every joint
            # until it is gone and a reset comes.
            events_before = len(graph.events)
            stray = graph.node.create_publisher(HasCommand, has_command_topic('left_hip'),
                                                qos_profile_sensor_data)
            assert graph.run(DISCOVERY_S, lambda: any(
                e.kind == SafetyKind.SECOND_SOURCE for e in graph.events[events_before:])), \
                [e.text for e in graph.events[events_before:]]
            [second] = [e for e in graph.events[events_before:]
                        if e.kind == SafetyKind.SECOND_SOURCE]
            assert second.severity == Severity.FATAL and second.joint == 'left_hip'
            assert '/robot_graph' in second.text and 'the robot loop' in second.text
            assert graph.run(2.0, lambda: graph.statuses[-1].level == DiagnosticStatus.ERROR)
            graph.node.destroy_publisher(stray)
            graph.run(1.0)
            graph.reset.publish(Empty())
            assert graph.run(10.0, graph.following), graph.errors_deg()
            fatal = [e.text for e in graph.events if e.severity == Severity.FATAL]
            assert fatal == [second.text]
            bridge.stop()
            loop.stop()
            assert loop.wait() == 0, loop.output

"""Gains of the running PD controller node: changed between commands, refused where unsafe."""

import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import qos_profile_sensor_data

from exo_has_control.pd_controller import PdController
from exo_has_msgs.msg import HasCommand, HasState

ERROR = 0.001  # m, the position error the joint is held at


class Bench:
    """The controller and a plant stand-in that sends states and reads the commands."""

    def __init__(self, context):
        self.controller = PdController(context=context, parameter_overrides=[
            Parameter('joints', value=['left_hip'])])
        self.plant = Node('plant_stand_in', context=context)
        self.states = self.plant.create_publisher(HasState, 'left_hip/has_state',
                                                  qos_profile_sensor_data)
        self.commands = []
        self.plant.create_subscription(HasCommand, 'left_hip/has_command',
                                       self.commands.append, qos_profile_sensor_data)
        self.executor = SingleThreadedExecutor(context=context)
        for node in (self.controller, self.plant):
            self.executor.add_node(node)
        self.t = 100.0
        self.x0 = None

    def spin_until(self, done, timeout=10.0):
        """Spin both nodes until ``done()``."""
        deadline = time.monotonic() + timeout
        while not done():
            assert time.monotonic() < deadline, 'timed out'
            self.executor.spin_once(timeout_sec=0.01)

    def command_at(self, position):
        """Send one state at ``position`` [m], 5 ms after the last; return the command."""
        self.t += 0.005
        state = HasState(joint='left_hip', position=position)
        state.header.stamp.sec, frac = int(self.t), self.t - int(self.t)
        state.header.stamp.nanosec = round(frac * 1e9)
        count = len(self.commands)
        self.states.publish(state)
        self.spin_until(lambda: len(self.commands) > count, timeout=2.0)
        return self.commands[-1].motor_speed

    def start(self):
        """Match, then hold the joint 1 mm under its first position at rest."""
        # The first state is the position held before any reference; discovery first.
        self.x0 = 0.02
        self.spin_until(lambda: self.states.get_subscription_count() > 0)
        deadline = time.monotonic() + 10.0
        while not self.commands:
            assert time.monotonic() < deadline, 'no command'
            self.states.publish(HasState(joint='left_hip', position=self.x0))
            self.executor.spin_once(timeout_sec=0.05)
        # Every state sent so far answered: a late answer must not pass for the next one's.
        quiet = time.monotonic() + 0.3
        while time.monotonic() < quiet:
            count = len(self.commands)
            self.executor.spin_once(timeout_sec=0.05)
            if len(self.commands) > count:
                quiet = time.monotonic() + 0.3
        self.command_at(self.x0 - ERROR)  # velocity settles to 0 from the next one on

    def close(self):
        """Destroy the nodes."""
        self.executor.shutdown()
        self.controller.destroy_node()
        self.plant.destroy_node()


@pytest.fixture
def bench(ros_context):
    bench = Bench(ros_context)
    bench.start()
    yield bench
    bench.close()


def test_a_gain_changed_mid_run_acts_on_the_next_command_and_an_unsafe_one_is_refused(bench):
    before = bench.command_at(bench.x0 - ERROR)
    assert before == pytest.approx(35000.0 * ERROR, rel=1e-6)
    result = bench.controller.set_parameters([Parameter('hip.kp', value=70000.0)])[0]
    assert result.successful, result.reason
    assert bench.command_at(bench.x0 - ERROR) == pytest.approx(70000.0 * ERROR, rel=1e-6)
    refused = bench.controller.set_parameters([Parameter('hip.kp', value=150500.0)])[0]
    assert not refused.successful
    assert 'unstable' in refused.reason and 'hip' in refused.reason
    assert bench.controller.get_parameter('hip.kp').value == 70000.0
    assert bench.command_at(bench.x0 - ERROR) == pytest.approx(70000.0 * ERROR, rel=1e-6)


def test_ros2_param_set_reaches_the_same_judgement_through_the_parameter_service(bench):
    client = AsyncParameterClient(bench.plant, 'pd_controller')
    bench.spin_until(lambda: client.services_are_ready())
    done = client.set_parameters([Parameter('hip.motor_speed_limit', value=500.0),
                                  Parameter('hip.kd', value=20.0)])
    bench.spin_until(done.done)
    limit, kd = done.result().results
    assert not limit.successful and 'motor top speed' in limit.reason
    assert kd.successful
    assert bench.controller.get_parameter('hip.kd').value == 20.0
    done = client.set_parameters([Parameter('joints', value=['left_knee'])])
    bench.spin_until(done.done)
    assert not done.result().results[0].successful  # read-only: rclpy refuses it

"""Plant node: one simulated HAS joint, stepped in real (or simulated) time.

Subscribes to the joint's HasCommand and to its external load (std_msgs/Float64, N), integrates
the model of :mod:`exo_has_sim.model` over the elapsed clock time at every tick, and publishes
the HasState with the valve mode. Run one per joint::

    ros2 run exo_has_sim plant --ros-args -p joint:=left_hip -r __node:=left_hip_plant
"""

from __future__ import annotations

import math
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Float64

from exo_has_msgs.msg import HasCommand, HasState
from exo_has_runtime.execution import run_node
from exo_has_runtime.joints import JOINT_NAMES, check_joint, joint_type_of
from exo_has_runtime.realtime import MAX_PRIORITY, set_realtime_priority
from exo_has_runtime.timing import PeriodMonitor
from exo_has_runtime.topics import (
    has_command_topic,
    has_state_topic,
    load_force_topic,
)
from exo_has_sim.loads import PAPER_LOAD_MASS, default_load_force
from exo_has_sim.parameters import load_parameters
from exo_has_sim.plant import Plant


class PlantNode(Node):
    """A simulated HAS joint: HasCommand and load in, HasState out."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('has_plant', **options)
        joint = self.declare_parameter('joint', '', ParameterDescriptor(
            description=f'joint simulated: one of {", ".join(JOINT_NAMES)}',
            read_only=True)).value
        if not joint:
            msg = f'parameter joint is required: one of {", ".join(JOINT_NAMES)}'
            raise ValueError(msg)
        self.joint = check_joint(joint)
        params_source = self.declare_parameter('params', joint_type_of(joint), ParameterDescriptor(
            description='HAS parameter set: hip, knee or a parameters YAML file',
            read_only=True)).value
        rate = self.declare_parameter('rate', 200.0, ParameterDescriptor(
            description='state publication and integration rate [Hz]', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=2000.0)])).value
        initial_angle = self.declare_parameter('initial_angle', 0.0, ParameterDescriptor(
            description='joint angle at start [rad], flexion positive (0: standing)',
            read_only=True)).value
        priority = self.declare_parameter('realtime_priority', 0, ParameterDescriptor(
            description='SCHED_FIFO priority of the thread that runs the ticks (0: the default '
                        'scheduler; needs root or CAP_SYS_NICE, see exo_has_runtime.realtime)',
            read_only=True,
            integer_range=[IntegerRange(from_value=0, to_value=MAX_PRIORITY, step=1)])).value
        params = load_parameters(params_source)
        mass = self.declare_parameter('load_mass', PAPER_LOAD_MASS, ParameterDescriptor(
            description='carried mass [kg] the default load_force is derived for (the paper: '
                        '50 kg in design, 25 kg in its tracking tests)', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=500.0)])).value
        load = self.declare_parameter('load_force', default_load_force(
            params, mass=mass, standing_angle=initial_angle), ParameterDescriptor(
            description='external rod force [N], positive pushing the cylinder in; the default '
                        'is the peak normative extensor moment for load_mass at the standing '
                        'lever arm (exo_has_sim.loads); <joint>/load_force replaces it',
            floating_point_range=[FloatingPointRange(from_value=-1.0e5, to_value=1.0e5)])).value
        self._plant = Plant(self.joint, params, initial_angle=initial_angle, load_force=load)
        self._period = 1.0 / rate
        self._plant.warm_up()  # compiles or loads the model's machine code before the first tick

        self._publisher = self.create_publisher(HasState, has_state_topic(self.joint),
                                                qos_profile_sensor_data)
        self.create_subscription(HasCommand, has_command_topic(self.joint), self._on_command,
                                 qos_profile_sensor_data)
        self.create_subscription(Float64, load_force_topic(self.joint), self._on_load, 10)
        self._last_ns: int | None = None
        self._timing = PeriodMonitor(round(self._period * 1e9))
        self.create_timer(self._period, self._on_tick)
        # This thread spins the node; the DDS threads, created earlier, stay ordinary.
        problem = set_realtime_priority(priority)
        if problem:
            self.get_logger().warning(f'realtime_priority: {problem}')
        self.get_logger().info(
            f'{self.joint} plant ready ({self._plant.params.joint_type} parameters from '
            f'{params_source}), {rate:g} Hz, load {load:.1f} N')

    def _on_command(self, command: HasCommand) -> None:
        problem = self._plant.command(command.joint, command.motor_speed, command.enable)
        if problem:
            self.get_logger().error(problem, throttle_duration_sec=1.0)

    def _on_load(self, message: Float64) -> None:
        if not math.isfinite(message.data):
            self.get_logger().error(f'ignored a non-finite load force {message.data!r} N',
                                    throttle_duration_sec=1.0)
            return
        self._plant.set_load(message.data)

    def _on_tick(self) -> None:
        now = self.get_clock().now()
        now_ns = now.nanoseconds
        self._timing.tick(now_ns)
        if self._last_ns is None or now_ns <= self._last_ns:
            # First tick, or simulated time has not advanced: nothing to integrate yet.
            self._last_ns = now_ns if self._last_ns is None else self._last_ns
            return
        elapsed = (now_ns - self._last_ns) * 1e-9
        self._last_ns = now_ns
        sample = self._plant.advance(elapsed)
        state = HasState(joint=self.joint, position=sample.position, velocity=sample.velocity,
                         pressure_a=sample.pressure_a, pressure_b=sample.pressure_b,
                         motor_speed=sample.motor_speed,
                         motor_speed_command=sample.motor_speed_command,
                         motor_current=math.nan, load_force=sample.load_force,
                         valve_mode=sample.valve_mode)
        state.header.stamp = now.to_msg()
        self._publisher.publish(state)

    def destroy_node(self) -> None:
        """Log the timing summary, then destroy the node."""
        self.get_logger().info(f'{self.joint} plant: {self._timing.summary()}')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run one plant until interrupted."""
    run_node(PlantNode, args, name='plant')


if __name__ == '__main__':
    main()

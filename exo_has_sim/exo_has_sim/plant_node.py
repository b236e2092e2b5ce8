"""Plant node: one simulated HAS joint, stepped in real (or simulated) time.

Subscribes to the joint's HasCommand and to what sets its external load: the gait publisher's
GaitPhase (``load_model:=gait``, the default: the joint's moment per kilogram of carried mass at
the published phase, over the lever arm at the joint's angle, at least the wearer's push; see
:mod:`exo_has_sim.loads`), or a constant ``load_force`` that a std_msgs/Float64 [N] on
``<joint>/load_force`` replaces (and that ends the gait load). Integrates the model of
:mod:`exo_has_sim.model` over the elapsed clock time at every tick, and publishes the HasState
with the valve mode and the load. Run one per joint::

    ros2 run exo_has_sim plant --ros-args -p joint:=left_hip -r __node:=left_hip_plant
"""

from __future__ import annotations

import math
from typing import Any

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Float64

from exo_has_common.joints import JOINT_NAMES, check_joint, joint_type_of
from exo_has_common.timing import PeriodMonitor
from exo_has_common.topics import (
    GAIT_PHASE_TOPIC,
    has_command_topic,
    has_state_topic,
    load_force_topic,
)
from exo_has_msgs.msg import GaitPhase, HasCommand, HasState
from exo_has_runtime.execution import run_node
from exo_has_runtime.node_parameters import (
    apply_realtime_priority,
    declare,
    declare_realtime_priority,
)
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import TRACKING_LOAD_MASS, JointLoad, default_load_force
from exo_has_sim.parameters import load_parameters
from exo_has_sim.plant import Plant
from exo_has_sim.state_message import has_state

#: How a plant's external load is set (parameter load_model).
LOAD_MODELS = ('gait', 'constant')


class PlantNode(Node):
    """A simulated HAS joint: HasCommand and load in, HasState out."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('has_plant', **options)
        joint = declare(self, 'joint', '', f'joint simulated: one of {", ".join(JOINT_NAMES)}')
        if not joint:
            msg = f'parameter joint is required: one of {", ".join(JOINT_NAMES)}'
            raise ValueError(msg)
        self.joint = check_joint(joint)
        params_source = declare(self, 'params', joint_type_of(joint),
                                'HAS parameter set: hip, knee or a parameters YAML file')
        rate = declare(self, 'rate', 200.0, 'state publication and integration rate [Hz]',
                       (1.0, 2000.0))
        initial_angle = declare(self, 'initial_angle', 0.0,
                                'joint angle at start [rad], flexion positive (0: standing)')
        priority = declare_realtime_priority(self, 'the thread that runs the ticks')
        params = load_parameters(params_source)
        load_model = declare(self, 'load_model', 'gait',
                             "gait: the load follows the gait publisher's gait_phase (the moment "
                             "per kg of load_mass over the lever arm, at least the wearer's "
                             "push); constant: load_force throughout")
        if load_model not in LOAD_MODELS:
            msg = f'load_model must be one of {", ".join(LOAD_MODELS)}, got {load_model!r}'
            raise ValueError(msg)
        mass = declare(self, 'load_mass', TRACKING_LOAD_MASS,
                       'carried mass [kg] the load is derived for (the paper: 25 kg in its '
                       'tracking tests, 50 kg in design)', (1.0, 500.0))
        load = declare(self, 'load_force',
                       default_load_force(params, mass=mass, standing_angle=initial_angle),
                       'constant external rod force [N] (load_model constant), positive pushing '
                       'the cylinder in; the default is the peak normative extensor moment for '
                       'load_mass at the standing lever arm (exo_has_sim.loads)',
                       (-1.0e5, 1.0e5), read_only=False)
        self._gait_load: JointLoad | None = None
        if load_model == 'gait':
            self._gait_load = JointLoad(params, mass)
            standing = float(Linkage.from_parameters(params).position(initial_angle))
            load = float(self._gait_load.force(0.0, standing))
        self._plant = Plant(self.joint, params, initial_angle=initial_angle, load_force=load)
        self._period = 1.0 / rate
        self._plant.warm_up()  # compiles or loads the model's machine code before the first tick

        self._publisher = self.create_publisher(HasState, has_state_topic(self.joint),
                                                qos_profile_sensor_data)
        self.create_subscription(HasCommand, has_command_topic(self.joint), self._on_command,
                                 qos_profile_sensor_data)
        self.create_subscription(Float64, load_force_topic(self.joint), self._on_load, 10)
        if self._gait_load is not None:
            self.create_subscription(GaitPhase, GAIT_PHASE_TOPIC, self._on_gait_phase,
                                     qos_profile_sensor_data)
        self._last_ns: int | None = None
        self._timing = PeriodMonitor(round(self._period * 1e9))
        self.create_timer(self._period, self._on_tick)
        describe = (f'along the gait for {mass:g} kg (at least {load:.1f} N)'
                    if self._gait_load is not None else f'{load:.1f} N')
        # This thread spins the node; the DDS threads, created earlier, stay ordinary.
        apply_realtime_priority(self, priority)
        self.get_logger().info(
            f'{self.joint} plant ready ({self._plant.params.joint_type} parameters from '
            f'{params_source}), {rate:g} Hz, load {describe}')

    def _on_command(self, command: HasCommand) -> None:
        problem = self._plant.command(command.joint, command.motor_speed, command.enable)
        if problem:
            self.get_logger().error(problem, throttle_duration_sec=1.0)

    def _on_load(self, message: Float64) -> None:
        if not math.isfinite(message.data):
            self.get_logger().error(f'ignored a non-finite load force {message.data!r} N',
                                    throttle_duration_sec=1.0)
            return
        if self._gait_load is not None:
            self._gait_load = None
            self.get_logger().info(f'{load_force_topic(self.joint)}: the load is '
                                   f"{message.data:.1f} N from now on, not the gait's")
        self._plant.set_load(message.data)

    def _on_gait_phase(self, message: GaitPhase) -> None:
        if self._gait_load is None:
            return
        joints = list(message.joints)
        if self.joint not in joints or len(message.moment_per_mass) != len(joints):
            self.get_logger().error(
                f'{GAIT_PHASE_TOPIC}: no moment for {self.joint} (joints {joints}, '
                f'{len(message.moment_per_mass)} moments); the load stays as it was',
                throttle_duration_sec=1.0)
            return
        moment = float(message.moment_per_mass[joints.index(self.joint)])
        if not math.isfinite(moment):
            self.get_logger().error(f'{GAIT_PHASE_TOPIC}: ignored a non-finite moment '
                                    f'{moment!r} N m/kg', throttle_duration_sec=1.0)
            return
        position = self._plant.sample().position
        self._plant.set_load(float(self._gait_load.force(moment, position)))

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
        self._publisher.publish(has_state(self.joint, now_ns, sample,
                                          load_force=sample.load_force))

    def destroy_node(self) -> None:
        """Log the timing summary, then destroy the node."""
        self.get_logger().info(f'{self.joint} plant: {self._timing.summary()}')
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run one plant until interrupted."""
    run_node(PlantNode, args, name='plant')


if __name__ == '__main__':
    main()

r"""Gait trajectory publisher: joint references for walking and squatting trials.

Publishes the four joints' reference angles and angular velocities as sensor_msgs/JointState
on ``joint_reference`` at a fixed rate: the trials listed in ``motions`` and ``durations`` back
to back, each starting and ending standing (exo_has_control.trajectory), then standing, and with
each reference the motion's phase and every joint's moment per kilogram of carried mass as
exo_has_msgs/GaitPhase on ``gait_phase``, from which the plants take their loads. Walking
follows a normative gait table (Winter's by default; ``gait_file`` takes any CSV of the same
shape, such as CGA data), the right leg half a cycle behind the left::

    ros2 run exo_has_control gait_publisher --ros-args \\
        -p motions:="['walk', 'squat']" -p durations:="[10.0, 8.0]"
"""

from __future__ import annotations

import math
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from exo_has_control.trajectory import JOINTS, ReferenceTable, Schedule, TrialPlan
from exo_has_msgs.msg import GaitPhase
from exo_has_runtime.execution import run_node
from exo_has_runtime.topics import GAIT_PHASE_TOPIC, JOINT_REFERENCE_TOPIC
from exo_has_sim.gait import WINTER, load_gait_cycle

MOTIONS = {'stand': GaitPhase.MOTION_STAND, 'walk': GaitPhase.MOTION_WALK,
           'squat': GaitPhase.MOTION_SQUAT}


def _range(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=low, to_value=high)]


class GaitPublisher(Node):
    """Publish the schedule's joint references from the first tick on."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('gait_publisher', **options)
        declare = self.declare_parameter
        motions = list(declare('motions', ['walk'], ParameterDescriptor(
            description='trials in order: walk, squat or stand', read_only=True)).value)
        durations = list(declare('durations', [20.0], ParameterDescriptor(
            description='length of each trial [s], ramps included', read_only=True)).value)
        ramp = declare('ramp', 1.0, ParameterDescriptor(
            description='smooth start and stop of each trial [s]', read_only=True,
            floating_point_range=_range(0.0, 60.0))).value
        stride = declare('stride_frequency', 0.85, ParameterDescriptor(
            description='walking strides per second [Hz] (the paper: 0.85)', read_only=True,
            floating_point_range=_range(0.05, 3.0))).value
        squat = declare('squat_frequency', 0.5, ParameterDescriptor(
            description='squats per second [Hz] (the paper: 0.5)', read_only=True,
            floating_point_range=_range(0.05, 3.0))).value
        squat_hip = declare('squat_hip', math.radians(40.0), ParameterDescriptor(
            description='hip flexion at the bottom of a squat [rad]', read_only=True,
            floating_point_range=_range(0.0, 2.0))).value
        squat_knee = declare('squat_knee', math.radians(70.0), ParameterDescriptor(
            description='knee flexion at the bottom of a squat [rad]', read_only=True,
            floating_point_range=_range(0.0, 2.5))).value
        gait_file = declare('gait_file', '', ParameterDescriptor(
            description='normative gait CSV (cycle_percent, hip_angle, knee_angle in deg); '
                        "empty: Winter's normal-cadence table", read_only=True)).value
        delay = declare('start_delay', 1.0, ParameterDescriptor(
            description='time from start-up to the first reference [s], for subscribers '
                        '(controller, recorder) to match first', read_only=True,
            floating_point_range=_range(0.0, 60.0))).value
        rate = declare('rate', 200.0, ParameterDescriptor(
            description='publication rate [Hz]', read_only=True,
            floating_point_range=_range(1.0, 2000.0))).value
        self._subscribers = declare('wait_for_subscribers', 0, ParameterDescriptor(
            description='subscribers of joint_reference to wait for before start_delay runs '
                        '(a session: its controller, watchdog and recorder), since a best-effort '
                        'reference reaches only the readers discovery has matched by then',
            read_only=True, integer_range=[IntegerRange(from_value=0, to_value=100, step=1)])
        ).value
        if len(motions) != len(durations):
            msg = (f'motions ({len(motions)}) and durations ({len(durations)}) must have the '
                   'same length')
            raise ValueError(msg)
        self._schedule = Schedule(tuple(
            TrialPlan(motion, float(duration), ramp=min(ramp, float(duration) / 2.0),
                      stride_frequency=stride, squat_frequency=squat, squat_hip=squat_hip,
                      squat_knee=squat_knee)
            for motion, duration in zip(motions, durations, strict=True)))
        self._gait = load_gait_cycle(gait_file or WINTER)
        self._table = ReferenceTable(self._schedule, self._gait)
        self._publisher = self.create_publisher(JointState, JOINT_REFERENCE_TOPIC,
                                                qos_profile_sensor_data)
        self._phase_publisher = self.create_publisher(GaitPhase, GAIT_PHASE_TOPIC,
                                                      qos_profile_sensor_data)
        self._delay_ns = round(delay * 1e9)
        self._start_ns: int | None = None
        self._trial = -1
        self.create_timer(1.0 / rate, self._on_tick)
        plan = ', '.join(f'{p.motion} {p.duration:g} s' for p in self._schedule.plans)
        waiting = (f'{self._subscribers} subscribers and ' if self._subscribers else '')
        self.get_logger().info(f'gait publisher ready: {plan} at {rate:g} Hz after {waiting}'
                               f'{delay:g} s, gait data from {self._gait.source}')

    def _on_tick(self) -> None:
        now = self.get_clock().now()
        if self._start_ns is None:
            if self._publisher.get_subscription_count() < self._subscribers:
                return
            if self._subscribers:
                self.get_logger().info(f'{self._subscribers} subscribers matched: trials start '
                                       f'in {self._delay_ns * 1e-9:g} s')
            self._start_ns = now.nanoseconds + self._delay_ns
        if now.nanoseconds < self._start_ns:
            return
        t = (now.nanoseconds - self._start_ns) * 1e-9
        angles, rates, moments = self._table.sample(t)
        self._log_progress(t)
        stamp = now.to_msg()
        message = JointState(name=list(JOINTS), position=angles, velocity=rates)
        message.header.stamp = stamp
        self._publisher.publish(message)
        motion, phase, amplitude = self._schedule.phase_at(t)
        gait_phase = GaitPhase(motion=MOTIONS[motion], phase=phase, amplitude=amplitude,
                               joints=list(JOINTS), moment_per_mass=moments)
        gait_phase.header.stamp = stamp
        self._phase_publisher.publish(gait_phase)

    def _log_progress(self, t: float) -> None:
        trial = self._schedule.trial_at(t)
        if trial == self._trial:
            return
        if trial >= 0:
            plan = self._schedule.plans[trial]
            self.get_logger().info(f'trial {trial + 1}/{len(self._schedule.plans)}: '
                                   f'{plan.motion} for {plan.duration:g} s')
        elif self._trial >= 0:
            self.get_logger().info('all trials done: standing')
        self._trial = trial


def main(args: list[str] | None = None) -> None:
    """Run the gait publisher until interrupted."""
    run_node(GaitPublisher, args, name='gait_publisher')


if __name__ == '__main__':
    main()

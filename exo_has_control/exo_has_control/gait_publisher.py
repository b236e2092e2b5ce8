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

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from exo_has_common.topics import GAIT_PHASE_TOPIC, JOINT_REFERENCE_TOPIC
from exo_has_control.trajectory import JOINTS, ReferenceTable, Schedule, TrialPlan
from exo_has_msgs.msg import GaitPhase
from exo_has_runtime.execution import run_node
from exo_has_runtime.node_parameters import declare
from exo_has_sim.gait import WINTER, load_gait_cycle

MOTIONS = {'stand': GaitPhase.MOTION_STAND, 'walk': GaitPhase.MOTION_WALK,
           'squat': GaitPhase.MOTION_SQUAT}


class GaitPublisher(Node):
    """Publish the schedule's joint references from the first tick on."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('gait_publisher', **options)
        motions = list(declare(self, 'motions', ['walk'],
                               'trials in order: walk, squat or stand'))
        durations = list(declare(self, 'durations', [20.0],
                                 'length of each trial [s], ramps included'))
        ramp = declare(self, 'ramp', 1.0, 'smooth start and stop of each trial [s]', (0.0, 60.0))
        stride = declare(self, 'stride_frequency', 0.85,
                         'walking strides per second [Hz] (the paper: 0.85)', (0.05, 3.0))
        squat = declare(self, 'squat_frequency', 0.5,
                        'squats per second [Hz] (the paper: 0.5)', (0.05, 3.0))
        squat_hip = declare(self, 'squat_hip', math.radians(40.0),
                            'hip flexion at the bottom of a squat [rad]', (0.0, 2.0))
        squat_knee = declare(self, 'squat_knee', math.radians(70.0),
                             'knee flexion at the bottom of a squat [rad]', (0.0, 2.5))
        gait_file = declare(self, 'gait_file', '',
                            'normative gait CSV (cycle_percent, hip_angle, knee_angle in deg); '
                            "empty: Winter's normal-cadence table")
        delay = declare(self, 'start_delay', 1.0,
                        'time from start-up to the first reference [s], for subscribers '
                        '(controller, recorder) to match first', (0.0, 60.0))
        rate = declare(self, 'rate', 200.0, 'publication rate [Hz]', (1.0, 2000.0))
        self._subscribers = declare(
            self, 'wait_for_subscribers', 0,
            'subscribers of joint_reference to wait for before start_delay runs (a session: '
            'its controller, watchdog and recorder), since a best-effort reference reaches '
            'only the readers discovery has matched by then', (0, 100))
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
        sample = self._table.sample(t)
        self._log_progress(t)
        stamp = now.to_msg()
        message = JointState(name=list(JOINTS), position=sample.angles, velocity=sample.rates)
        message.header.stamp = stamp
        self._publisher.publish(message)
        gait_phase = GaitPhase(motion=MOTIONS[sample.motion], phase=sample.phase,
                               amplitude=sample.amplitude, joints=list(JOINTS),
                               moment_per_mass=sample.moments)
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

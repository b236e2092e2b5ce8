"""The robot loop's ROS bridge: a managed node, the topics users know, the loop's sockets.

The robot loop (:mod:`exo_has_bringup.robot_main`) runs the bus, the safety rules and the PD law
without ROS; this node is its face on the ROS graph, and may be late, stall or die without the
loop being late (:mod:`exo_has_bringup.robot_exchange`: neither end waits)::

    ros2 run exo_has_bringup robot_bridge --ros-args -p socket_dir:=/run/exo_has

It is a managed (lifecycle) node whose transitions are the loop's, as a ros2_control hardware
component's or a ros2_canopen driver's are: configure opens the bus and checks the devices,
activate enables the drives and starts following the reference, deactivate holds every joint,
cleanup releases the bus (:mod:`.robot_main` says what each does there). Each transition waits
for the loop's answer and fails with the loop's reason (a device named) or when the loop does
not answer. With ``autostart`` (the default) the node configures and activates itself at
start, as the hardware driver node does; otherwise a lifecycle manager calls
``/robot_bridge/change_state``. A loop that is configured or active already (a bridge that
restarts) answers each transition at once: a hold the loop keeps, after the bridge was lost,
lasts until a reset. When the bridge ends, the loop carries on alone; the reference it stops
receiving is stale and every joint holds.

In: ``joint_reference`` (sensor_msgs/JointState, rad and rad/s, by name) to the loop as each
arrives; ``safety_reset`` (std_msgs/Empty) as a reset request; every ``status_period`` whether
the reference's publisher is in the graph (one that left withdrew its reference: the loop does
not hold for it; a bridge that falls silent is no such withdrawal, and the loop holds). The
gains, ``hip.kp`` ... ``knee.motor_speed_limit`` as the PD controller node has them
(:mod:`exo_has_control.gain_parameters`), are judged here at the loop's ``rate`` and refused
with the reason where unsafe, else sent; the loop applies them between two periods. They are
sent again every ``diagnostics_period``, so that a loop that restarted runs with them.

Out, every period of ``rate``: what the loop sent since the last, each sample as
``<joint>/has_state`` (stamped with its hardware receive time), each event on ``safety_events``
(``SAFETY_EVENT_QOS``, stamped when the loop raised it), and every ``diagnostics_period`` the
loop's timing on ``/diagnostics`` (status ``robot_loop``: periods, missed, lateness, longest gap
between bus commands, datagrams dropped, each since the loop started; STALE while the loop is
silent). The level judges the window since the previous status, as diagnostic_updater's
frequency status does: WARN for periods missed in it, OK again in the next window without any.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty

from exo_has_bringup.robot_exchange import bridge_end, default_directory
from exo_has_bringup.robot_messages import (
    BridgeStatus,
    EventMessage,
    GainChange,
    HeldConditions,
    LifecycleRequest,
    LoopMode,
    LoopState,
    Message,
    Metrics,
    Reference,
    ResetRequest,
    States,
    Transition,
)
from exo_has_common.joints import JOINT_NAMES, JOINT_TYPES
from exo_has_common.topics import (
    DIAGNOSTICS_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_control.gain_parameters import declare_gains, declare_parameter_set, gain_changes
from exo_has_control.pd import PdGains
from exo_has_driver.messages import safety_event
from exo_has_driver.second_source import second_source
from exo_has_msgs.msg import HasState, SafetyEvent
from exo_has_runtime.execution import run_node
from exo_has_runtime.graph import PublisherWatch
from exo_has_runtime.node_parameters import declare
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_sim.parameters import HasParameters
from exo_has_sim.state_message import has_state, nanoseconds

#: Name of the loop's status on ``/diagnostics``.
DIAGNOSTIC_NAME = 'robot_loop'
#: How long a transition waits for the loop's answer [s]: a configure boots and checks every
#: device (the master's boot and SDO timeouts), an activation waits for the drives.
ANSWER_TIMEOUT = {Transition.CONFIGURE: 30.0, Transition.ACTIVATE: 10.0,
                  Transition.DEACTIVATE: 2.0, Transition.CLEANUP: 10.0}
#: How often a transition looks for the answer [s].
ANSWER_POLL = 0.005
#: Longest wait of the reader thread for a datagram [s]: how soon it sees the node end.
READ_WAIT = 0.1


class RobotBridge(LifecycleNode):
    """Topics to and from the robot loop's sockets; see the module docstring."""

    def __init__(self, **options: Any) -> None:
        super().__init__('robot_bridge', **options)
        directory = declare(self, 'socket_dir', str(default_directory()),
                            "directory of the robot loop's sockets")
        rate = declare(self, 'rate', 200.0,
                       "the loop's rate [Hz]: gains are judged at its period, and what the loop "
                       'sent is published at it', (1.0, 1000.0))
        status_period = declare(self, 'status_period', 0.05,
                                "period [s] of the reference publisher's presence sent to the "
                                'loop', (0.005, 1.0))
        source_period = declare(self, 'source_check_period', 0.1,
                                "period [s] of the check for a second source of a joint's states "
                                'or commands', (0.01, 10.0))
        self._diagnostics_period = declare(
            self, 'diagnostics_period', 1.0,
            "period [s] of the loop's status on /diagnostics and of the gains sent again",
            (0.05, 10.0))
        autostart = declare(self, 'autostart', True,
                            'configure and activate at start (else a lifecycle manager does)')
        self._period = 1.0 / rate
        self._params: dict[str, HasParameters] = {}
        self._gains: dict[str, PdGains] = {}
        for kind in JOINT_TYPES:
            self._params[kind] = declare_parameter_set(self, kind)
            self._gains[kind] = declare_gains(self, self._params[kind], self._period)
        self._exchange = bridge_end(Path(directory))
        self._inbox: collections.deque[Message] = collections.deque()
        self._closing = threading.Event()
        self._reader = threading.Thread(target=self._read, name='robot-bridge-reader',
                                        daemon=True)
        self._reader.start()
        self._state_publishers = {
            joint: self.create_publisher(HasState, has_state_topic(joint),
                                         qos_profile_sensor_data)
            for joint in JOINT_NAMES}
        self._event_publisher = self.create_publisher(SafetyEvent, SAFETY_EVENT_TOPIC,
                                                      SAFETY_EVENT_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._metrics: Metrics | None = None
        self._metrics_received = -math.inf  # monotonic time [s] of the newest metrics
        self._loop_mode: LoopMode | None = None  # the loop's newest report of its state
        self._mode_received = -math.inf  # monotonic time [s] of that report
        # The loop's metrics when the previous status was judged; None: no status judged yet,
        # so the window is the loop's whole run.
        self._judged: Metrics | None = None
        self._request = 0
        self._failure = ''  # why the last transition failed
        self.create_subscription(JointState, JOINT_REFERENCE_TOPIC, self._on_reference,
                                 qos_profile_sensor_data)
        self.create_subscription(Empty, SAFETY_RESET_TOPIC, self._on_reset, 10)
        self.create_timer(self._period, self._on_tick)
        self.create_timer(status_period, self._on_status)
        self.create_timer(self._diagnostics_period, self._on_diagnostics)
        # The loop commands the joints and this node publishes their states: any other
        # publisher of either (a controller, a plant, a driver left running) is a fault the
        # loop holds (the watchdog's and the driver's rule).
        self._commanders = PublisherWatch(self, [has_command_topic(j) for j in JOINT_NAMES],
                                          source=True)
        self._state_sources = PublisherWatch(self, [has_state_topic(j) for j in JOINT_NAMES],
                                             source=True)
        self._joint_of_topic = {
            topic: joint for watch in (self._commanders, self._state_sources)
            for topic, joint in zip(watch.topics, JOINT_NAMES, strict=True)}
        self.create_timer(source_period, self._on_source_check)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # rclpy 7.1.6 raises out of the change_state service on a transition the current
        # state does not have, which ends the node (ros2/rclpy#1209, fixed upstream by #1319
        # after this release): such a request is refused here, as rclcpp refuses it.
        self._change_state = self._service_change_state.callback
        self._service_change_state.callback = self._on_change_state
        self._send_gains(self._gains)
        where = f'sockets in {self._exchange.own.parent}'
        if not autostart:
            self.get_logger().info(f'robot bridge ready: unconfigured, {where}')
        elif self.trigger_configure() == TransitionCallbackReturn.SUCCESS \
                and self.trigger_activate() == TransitionCallbackReturn.SUCCESS:
            self.get_logger().info(f'robot bridge ready: active, {where}')
        else:
            self.get_logger().error(f'robot bridge not started: {self._failure}; {where}')

    # --- the lifecycle: each transition is the loop's ----------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Have the loop open the bus and check the devices."""
        return self._ask(Transition.CONFIGURE)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Have the loop enable the drives and follow the reference."""
        result = self._ask(Transition.ACTIVATE)
        if result == TransitionCallbackReturn.SUCCESS:
            self._send_gains(self._gains)
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Have the loop hold every joint where it stands."""
        return self._ask(Transition.DEACTIVATE)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Have the loop stop the drives and release the bus."""
        return self._ask(Transition.CLEANUP)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Have the loop hold, then release the bus (from whatever state the node is in)."""
        if state.label == 'active' and self._ask(Transition.DEACTIVATE) != \
                TransitionCallbackReturn.SUCCESS:
            return TransitionCallbackReturn.FAILURE
        if state.label == 'unconfigured':
            return TransitionCallbackReturn.SUCCESS
        return self._ask(Transition.CLEANUP)

    def _on_change_state(self, request: ChangeState.Request,
                         response: ChangeState.Response) -> ChangeState.Response:
        """Refuse a transition the current state does not have; else carry it out."""
        wanted = request.transition
        available = self._state_machine.available_transitions
        if not wanted.label and wanted.id not in [transition[0] for transition in available]:
            state = self._state_machine.current_state[1]
            names = ', '.join(transition[1] for transition in available)
            self.get_logger().warning(f'transition {wanted.id} refused: {state} has only '
                                      f'{names}')
            response.success = False
            return response
        return self._change_state(request, response)

    def _ask(self, transition: Transition) -> TransitionCallbackReturn:
        """Ask the loop for a transition and wait for its answer, forwarding what it sends."""
        self._request += 1
        request = self._request
        self._exchange.send(LifecycleRequest(transition, request))
        timeout = ANSWER_TIMEOUT[transition]
        deadline = time.monotonic() + timeout
        name = transition.name.lower()
        while time.monotonic() < deadline:
            for message in self._take_inbox():
                if isinstance(message, LoopState) and message.request == request:
                    if message.ok:
                        self.get_logger().info(f'{name}: the robot loop is '
                                               f'{message.mode.name.lower()}')
                        return TransitionCallbackReturn.SUCCESS
                    self._failure = f'{name} refused by the robot loop: {message.text}'
                    self.get_logger().error(self._failure)
                    return TransitionCallbackReturn.FAILURE
            time.sleep(ANSWER_POLL)
        self._failure = (f'{name}: no answer from the robot loop within {timeout:g} s (is it '
                         f'running, with its sockets in {self._exchange.own.parent}?)')
        self.get_logger().error(self._failure)
        return TransitionCallbackReturn.FAILURE

    def _on_reference(self, reference: JointState) -> None:
        if len(reference.position) != len(reference.name):
            self.get_logger().warning('ignored a joint reference without a position per name',
                                      throttle_duration_sec=1.0)
            return
        chosen = [index for index, name in enumerate(reference.name) if name in JOINT_NAMES]
        if not chosen:
            return
        rates = reference.velocity if len(reference.velocity) == len(reference.name) else None
        self._exchange.send(Reference(
            time.monotonic(), tuple(reference.name[i] for i in chosen),
            tuple(float(reference.position[i]) for i in chosen),
            tuple(float(rates[i]) if rates is not None else 0.0 for i in chosen)))

    def _on_reset(self, _: Empty) -> None:
        self._exchange.send(ResetRequest())

    def _on_status(self) -> None:
        self._exchange.send(BridgeStatus(self.count_publishers(JOINT_REFERENCE_TOPIC) > 0))

    def _on_source_check(self) -> None:
        now = time.monotonic()
        found = []
        for watch, own in ((self._commanders, 'the robot loop'),
                           (self._state_sources, 'the robot bridge')):
            for topic, names in watch.poll(now).items():
                condition = second_source(self._joint_of_topic[topic], topic, names, own=own)
                if condition is not None:
                    found.append(replace(condition, key=topic))  # the datagram's key: a string
        self._exchange.send(HeldConditions(tuple(found)))

    def _on_tick(self) -> None:
        self._take_inbox()

    def _read(self) -> None:
        """Read the loop's datagrams as they come, into the inbox (a thread of its own).

        The kernel queues at most ``net.unix.max_dgram_qlen`` (10 by default) datagrams on a
        Unix socket: read on the executor's timer, the states were dropped whenever the
        executor was 10 periods late (at 1 kHz, 10 ms: a quarter of them under load).
        """
        exchange, inbox = self._exchange, self._inbox
        while not self._closing.is_set():
            if exchange.wait(READ_WAIT):
                inbox.extend(exchange.receive())

    def _take_inbox(self) -> list[Message]:
        """Publish and keep what the loop sent since the last call; return it."""
        taken = []
        inbox = self._inbox
        while inbox:
            message = inbox.popleft()
            self._take(message)
            taken.append(message)
        return taken

    def _take(self, message: Message) -> None:
        """Publish what the loop sent; keep its metrics and its state."""
        if isinstance(message, States):
            for sample in message.samples:
                self._state_publishers[sample.joint].publish(has_state(
                    sample.joint, nanoseconds(sample.stamp), sample,
                    motor_current=sample.motor_current))
        elif isinstance(message, EventMessage):
            self._event_publisher.publish(safety_event(message.event, self._wall_ns(
                message.t)))
        elif isinstance(message, Metrics):
            self._metrics = message
            self._metrics_received = time.monotonic()
        elif isinstance(message, LoopState):
            self._loop_mode = message.mode
            self._mode_received = time.monotonic()

    @staticmethod
    def _wall_ns(t: float) -> int:
        """Return the wall-clock time [ns] of a time ``t`` [s] on this host's monotonic clock."""
        return nanoseconds(time.time() - (time.monotonic() - t))

    def _on_diagnostics(self) -> None:
        self._send_gains(self._gains)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [self._status()]
        self._diagnostics.publish(array)

    def _status(self) -> DiagnosticStatus:
        """Return the loop's status from its newest metrics; STALE when it fell silent."""
        metrics = self._metrics
        now = time.monotonic()
        silent = now - self._metrics_received
        if self._loop_mode is LoopMode.UNCONFIGURED \
                and now - self._mode_received <= 2.0 * self._diagnostics_period:
            return DiagnosticStatus(level=DiagnosticStatus.WARN, name=DIAGNOSTIC_NAME,
                                    message='unconfigured: the bus is closed',
                                    values=[KeyValue(key='lifecycle state', value='unconfigured'),
                                            KeyValue(key='problem', value=self._failure)])
        if metrics is None or silent > 2.0 * self._diagnostics_period:
            heard = 'no metrics from the robot loop yet' if metrics is None else \
                f'no metrics from the robot loop for {silent:.1f} s'
            return DiagnosticStatus(level=DiagnosticStatus.STALE, name=DIAGNOSTIC_NAME,
                                    message=heard)
        # Every status with metrics ends a window, whichever level it reports.
        missed = self._missed_since_previous(metrics)
        if self._loop_mode is not LoopMode.ACTIVE:
            mode = 'unknown' if self._loop_mode is None else self._loop_mode.name.lower()
            level, text = DiagnosticStatus.WARN, f'{mode}: the loop follows no reference'
        elif metrics.stopped:
            level, text = DiagnosticStatus.ERROR, 'stopped: every joint disabled until a reset'
        elif metrics.holding:
            level, text = DiagnosticStatus.WARN, 'holding: the reference was lost; every ' \
                'joint holds until a reset'
        elif missed:
            level, text = DiagnosticStatus.WARN, f'running; {missed}'
        else:
            level, text = DiagnosticStatus.OK, 'running'
        mode = 'unknown' if self._loop_mode is None else self._loop_mode.name.lower()
        values = (('lifecycle state', mode),
                  ('periods', f'{metrics.periods}'), ('missed', f'{metrics.missed}'),
                  ('late', f'{metrics.late}'),
                  ('lateness p99 [ms]', f'{metrics.lateness_p99 * 1e3:.3f}'),
                  ('lateness p99.9 [ms]', f'{metrics.lateness_p999 * 1e3:.3f}'),
                  ('lateness max [ms]', f'{metrics.lateness_max * 1e3:.3f}'),
                  ('longest gap [ms]', f'{metrics.longest_gap * 1e3:.3f}'),
                  ('cycle compute max [ms]', f'{metrics.compute_max * 1e3:.3f}'),
                  ('cycle compute mean [ms]', f'{metrics.compute_mean * 1e3:.3f}'),
                  ('datagrams dropped', f'{metrics.dropped}'),
                  ('datagrams refused', f'{metrics.malformed}'),
                  ('problem', metrics.problem))
        return DiagnosticStatus(level=level, name=DIAGNOSTIC_NAME, message=text,
                                values=[KeyValue(key=k, value=v) for k, v in values])

    def _missed_since_previous(self, metrics: Metrics) -> str:
        """Say how many periods the loop missed since the previous status; empty if none."""
        before = self._judged
        if before is not None and metrics.periods < before.periods:
            before = None  # the loop restarted: its counts start again
        self._judged = metrics
        missed = metrics.missed - (0 if before is None else before.missed)
        if not missed:
            return ''
        window = 'since the loop started' if before is None else \
            f'in the last {metrics.t - before.t:.1f} s'
        return f'{missed} periods missed {window} ({metrics.missed} in all)'

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Judge a change of gains at the loop's rate; send it where safe, refuse it otherwise."""
        accepted, reason = gain_changes(parameters, self._gains, self._params, self._period)
        if reason:
            self.get_logger().warning(f'gain change refused: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self._gains.update(accepted)
        self._send_gains(accepted)
        for kind, gains in accepted.items():
            self.get_logger().info(f'{kind} gains sent to the loop: kp {gains.kp:g}, kd '
                                   f'{gains.kd:g}, kff {gains.kff:.5g}, limit '
                                   f'{gains.speed_limit:.5g}')
        return SetParametersResult(successful=True)

    def _send_gains(self, gains: dict[str, PdGains]) -> None:
        for kind, g in gains.items():
            self._exchange.send(GainChange(kind, g.kp, g.kd, g.kff, g.speed_limit))

    def destroy_node(self) -> None:
        """End the reader, close the socket, then destroy the node."""
        self._closing.set()
        self._reader.join(timeout=2.0 * READ_WAIT + 1.0)
        self._exchange.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run the bridge until interrupted."""
    run_node(RobotBridge, args, name='robot_bridge')


if __name__ == '__main__':
    main()

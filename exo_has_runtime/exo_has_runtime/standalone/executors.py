"""Executors for the standalone backend, shaped as ``rclpy.executors``.

One Cyclone DDS wait set holds a read condition per subscription, the context's guard condition
(shutdown) and the discovery readers; the wait ends at the first of new data, shutdown, the next
timer or the caller's timeout. Each :meth:`SingleThreadedExecutor.spin_once` then runs every
callback that is ready (rclpy runs one), subscriptions first, then due timers. An executor made
with ``wake_on_messages=False`` leaves the read conditions out and takes the messages when a
timer is due: see :class:`SingleThreadedExecutor`.
"""

from __future__ import annotations

import time
from typing import Any

from cyclonedds.core import DDSException, WaitSet

from exo_has_runtime.errors import ExternalShutdownException, RuntimeSeamError
from exo_has_runtime.standalone.context import Context, get_default_context
from exo_has_runtime.standalone.node import Node

# Longest single wait: the Python-level SIGINT handler only runs between waits.
_MAX_WAIT_NS = 100_000_000


class SingleThreadedExecutor:
    """Runs the callbacks of its nodes in the calling thread.

    Parameters
    ----------
    context : Context, optional
        The context (default: the process-wide one).
    wake_on_messages : bool
        True (rclpy's behaviour): wake for every arrival. False: wake for timers only, and take
        the waiting messages just before the due timers run, for a node whose work is paced by
        its timers (a plant, a watchdog, a recorder): it then costs one wake-up per tick
        instead of one per message. Its readers must be deep enough to hold the messages of
        one tick. Not rclpy API: :func:`exo_has_runtime.spin_paced` chooses it.

    """

    def __init__(self, *, context: Context | None = None, wake_on_messages: bool = True) -> None:
        self.context = context if context is not None else get_default_context()
        self.wake_on_messages = wake_on_messages
        self._nodes: list[Node] = []
        self._waitset: WaitSet | None = None
        self._attached_version: tuple[int, ...] | None = None
        self._subscriptions: list[Any] = []
        self._timer_list: list[Any] = []
        self._shutdown = False

    def add_node(self, node: Node) -> bool:
        """Add a node; return False if it was there already."""
        if node in self._nodes:
            return False
        self._nodes.append(node)
        return True

    def remove_node(self, node: Node) -> None:
        """Remove a node."""
        if node in self._nodes:
            self._nodes.remove(node)

    def get_nodes(self) -> list[Node]:
        """Return the nodes."""
        return list(self._nodes)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Stop spinning and forget the nodes."""
        self._shutdown = True
        self._nodes.clear()
        return True

    def _ready_waitset(self) -> WaitSet:
        """Return the wait set, rebuilt with the entity lists when a node's entities change."""
        version = tuple(node.entities_version for node in self._nodes)
        if self._waitset is None or version != self._attached_version:
            waitset = WaitSet(self.context.participant)
            waitset.attach(self.context.guard_condition)
            for condition in self.context.graph_conditions:
                waitset.attach(condition)
            self._subscriptions = [s for node in self._nodes for s in node.subscriptions]
            self._timer_list = [t for node in self._nodes for t in node.timers]
            if self.wake_on_messages:
                for subscription in self._subscriptions:
                    waitset.attach(subscription.condition)
            self._waitset = waitset
            self._attached_version = version
        return self._waitset

    def _stopped(self) -> bool:
        """Whether to stop; finish a SIGTERM's shutdown and raise as rclpy does.

        Raises
        ------
        ExternalShutdownException
            If a SIGTERM asked the context to shut down.

        """
        if self.context.shut_down_externally:
            self.context.try_shutdown()
            raise ExternalShutdownException('the context was shut down by a signal')
        return not self.context.ok() or self._shutdown

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait for work up to ``timeout_sec`` (None: until some arrives) and do it.

        Returns at once when the context is shut down.

        Raises
        ------
        ExternalShutdownException
            If a SIGTERM shuts the context down.

        """
        deadline = None if timeout_sec is None or timeout_sec < 0 \
            else time.monotonic_ns() + int(timeout_sec * 1e9)
        while True:
            if self._stopped():
                return
            waitset = self._ready_waitset()
            wait_ns = _MAX_WAIT_NS
            for timer in self._timer_list:
                due = timer.due_in(timer.clock.now_ns())
                if due is not None and due < wait_ns:
                    wait_ns = due
            if deadline is not None:
                wait_ns = min(wait_ns, max(0, deadline - time.monotonic_ns()))
            try:
                triggered = waitset.wait(wait_ns)
                if self._stopped():
                    return
                worked = self._run_ready(triggered > 0)
            except (DDSException, RuntimeSeamError, RuntimeError):
                # A shutdown from a callback deletes the DDS entities under our feet.
                if self._stopped():
                    return
                raise
            if worked or (deadline is not None and time.monotonic_ns() >= deadline):
                return

    def _run_ready(self, triggered: bool) -> bool:
        worked = False
        if triggered and any(c.triggered for c in self.context.graph_conditions):
            self.context.refresh_graph()
        if triggered or not self.wake_on_messages:
            for subscription in self._subscriptions:
                # A callback may have destroyed it, or shut the context down.
                if subscription.destroyed or not self.context.ok():
                    continue
                callback = subscription.callback
                if subscription.wants_info:
                    for message, info in subscription.take_with_info():
                        callback(message, info)
                        worked = True
                else:
                    for message in subscription.take():
                        callback(message)
                        worked = True
        for timer in self._timer_list:
            now = timer.clock.now_ns()
            if timer.due_in(now) == 0:
                timer.call(now)
                worked = True
        return worked

    def spin(self) -> None:
        """Run callbacks until the context is shut down.

        Returns when the context is shut down (by a callback, say).

        Raises
        ------
        ExternalShutdownException
            When a SIGTERM shuts the context down.

        """
        while not self._stopped():
            self.spin_once()

    def spin_until_future_complete(self, future: Any, timeout_sec: float | None = None) -> None:
        """Spin until ``future.done()`` or the timeout."""
        deadline = None if timeout_sec is None else time.monotonic() + timeout_sec
        while not future.done():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return
            self.spin_once(remaining)


_global_executors: dict[int, SingleThreadedExecutor] = {}


def get_global_executor(context: Context | None = None) -> SingleThreadedExecutor:
    """Return the executor that module-level spin() and spin_once() use."""
    context = context if context is not None else get_default_context()
    executor = _global_executors.get(id(context))
    if executor is None or executor._shutdown:
        executor = SingleThreadedExecutor(context=context)
        _global_executors[id(context)] = executor
    return executor


def spin(node: Node, executor: SingleThreadedExecutor | None = None) -> None:
    """Run the node's callbacks until shutdown, as ``rclpy.spin``."""
    executor = executor if executor is not None else get_global_executor(node.context)
    try:
        executor.add_node(node)
        executor.spin()
    finally:
        executor.remove_node(node)


def spin_once(node: Node, *, executor: SingleThreadedExecutor | None = None,
              timeout_sec: float | None = None) -> None:
    """Do the node's ready work, waiting up to ``timeout_sec``, as ``rclpy.spin_once``."""
    executor = executor if executor is not None else get_global_executor(node.context)
    try:
        executor.add_node(node)
        executor.spin_once(timeout_sec=timeout_sec)
    finally:
        executor.remove_node(node)


def spin_paced(node: Node) -> None:
    """Run a node whose work is paced by its timers until shutdown (not rclpy API).

    The executor wakes for the node's timers only and hands it the messages that arrived since
    the last tick just before its due timers run (see :class:`SingleThreadedExecutor`). The
    node's readers must hold a tick's messages, and it needs a timer at the rate at which it
    must see its inputs.
    """
    executor = SingleThreadedExecutor(context=node.context, wake_on_messages=False)
    try:
        executor.add_node(node)
        executor.spin()
    finally:
        executor.remove_node(node)

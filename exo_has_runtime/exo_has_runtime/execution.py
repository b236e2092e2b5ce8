"""How every exo_has node is spun and started: one executor choice and one ``main()``.

The executor was chosen by measurement (bench/README.md): rclpy 7.1.6's
``SingleThreadedExecutor`` costs about 300 us of Python per callback, and a session on it
saturates this machine's two cores; on ``rclpy.experimental.EventsExecutor`` (C++) a plant
and its client take 0.4 to 0.6 of that CPU. Two defects of that release shape how it is used
here, and :mod:`exo_has_runtime.test.test_execution` fails if either changes:

- ``EventsExecutor.spin()`` never returns on SIGINT or SIGTERM while a timer runs (its C++
  loop does not see rclpy's signal handler shut the context down), whereas ``spin_once`` does
  return. So :func:`spin` calls ``spin_once`` in slices of :data:`SPIN_SLICE_S`.
- A subscription callback that takes the ``MessageInfo`` (``callback(message, info)``) makes
  ``EventsExecutor.spin_once`` raise ``SystemError: null argument to internal routine``. Node
  code here therefore takes one argument per callback; where a time of reception is wanted it
  reads the clock (as rosbag2 does for its ``recv_timestamp``).

Signals are handled here, not by rclpy: SIGINT, SIGTERM and SIGHUP ask the spin loop to end
after the callback under way, and the nodes are destroyed while their context is still valid, so
that their last words (a plant's timing summary, the recorder's closing counts) still reach
``/rosout`` and a bag is closed between two writes, never in the middle of one. rclpy's own
handler would shut the context down first.

``EXO_HAS_EXECUTOR=single`` runs a node on ``SingleThreadedExecutor`` instead: the benchmarks
compare the two side by side with it.

Once its nodes are built, a process moves every object it has made so far (the imports of
rclpy, numpy, scipy and numba, the nodes themselves) out of reach of Python's cyclic garbage
collector (``gc.freeze``). A full collection otherwise walks all of them with the GIL held: some
50 ms on this machine, a stall of every thread of the process, which showed as gaps of 30 to
90 ms in the plants' and the controller's streams (bench/stalls.py, bench/README.md "Stalls").
``EXO_HAS_GC_FREEZE=0`` leaves the collector as Python sets it, for that comparison.
"""

from __future__ import annotations

import gc
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence

import rclpy
from rclpy.context import Context
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import ok, try_shutdown

from exo_has_common.stopping import StopRequest
from exo_has_runtime.dds import configure_transport
from exo_has_runtime.errors import DdsConfigurationError

#: Longest time one ``spin_once`` may block [s]: how long a shutdown may go unnoticed.
SPIN_SLICE_S = 0.1

#: Signals that end a node cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

#: Executors a node can run on (``EXO_HAS_EXECUTOR``); the first is the default.
EXECUTORS = ('events', 'single')

#: What rcl raises for bad ROS arguments (a malformed params file, a bad remap) at ``init``.
RCLError: type[Exception] = rclpy_implementation.RCLError

#: What a node's constructor raises on a bad configuration (an unknown joint, a parameter of the
#: wrong type or out of range, an unreadable file): ``main`` logs it and exits 1, no traceback.
STARTUP_ERRORS: tuple[type[Exception], ...] = (
    ValueError, TypeError, LookupError, OSError, ParameterException,
    InvalidParameterTypeException, InvalidParameterValueException)


def executor_kind() -> str:
    """Return the executor chosen by ``EXO_HAS_EXECUTOR`` (default ``events``).

    Raises
    ------
    ValueError
        If the variable names no known executor.

    """
    kind = os.environ.get('EXO_HAS_EXECUTOR', EXECUTORS[0]).strip().lower() or EXECUTORS[0]
    if kind not in EXECUTORS:
        msg = f'EXO_HAS_EXECUTOR={kind!r}: expected one of {", ".join(EXECUTORS)}'
        raise ValueError(msg)
    return kind


def make_executor(kind: str | None = None, context: Context | None = None) -> Executor:
    """Return a new executor of a kind (``events`` or ``single``; default: the environment's).

    ``context`` is rclpy's default context unless given.
    """
    kind = executor_kind() if kind is None else kind
    if kind == 'events':
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    msg = f'unknown executor {kind!r}: expected one of {", ".join(EXECUTORS)}'
    raise ValueError(msg)


def spin(nodes: Node | Sequence[Node], executor: Executor | None = None,
         stop: threading.Event | StopRequest | None = None) -> None:
    """Run the nodes' callbacks until ``stop`` is set or their context shuts down.

    Parameters
    ----------
    nodes : Node or Sequence[Node]
        Nodes of one context.
    executor : Executor or None
        The executor; a new one of :func:`executor_kind` by default.
    stop : threading.Event or StopRequest or None
        Ends the loop once set (within :data:`SPIN_SLICE_S`).

    Raises
    ------
    ExternalShutdownException
        When the context was shut down from elsewhere, as :func:`rclpy.spin` does.

    """
    node_list = [nodes] if isinstance(nodes, Node) else list(nodes)
    context = node_list[0].context if node_list else None
    executor = make_executor(context=context) if executor is None else executor
    for node in node_list:
        executor.add_node(node)
    try:
        # spin_once in slices, not spin(): see the module docstring.
        while ok(context=context) and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=SPIN_SLICE_S)
    finally:
        executor.shutdown()


class _StopOnSignal:
    """While entered, SIGINT, SIGTERM and SIGHUP ask for a stop instead of interrupting."""

    def __init__(self) -> None:
        self.request = StopRequest()
        self._previous: dict[int, object] = {}

    def __enter__(self) -> StopRequest:
        for number in STOP_SIGNALS:
            self._previous[number] = signal.signal(number, self._on_signal)
        return self.request

    def __exit__(self, *exc: object) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)  # type: ignore[arg-type]

    def _on_signal(self, number: int, frame: object) -> None:
        self.request.set()


def run_nodes(factories: Sequence[Callable[[], Node]], args: Sequence[str] | None = None,
              name: str = 'exo_has') -> None:
    """Initialise rclpy, build the nodes, spin them on one executor, and clean up.

    This is the body of every node's ``main()``, in the shape of ros2/examples: ``init``; try
    spin; except ``KeyboardInterrupt`` and ``ExternalShutdownException``; finally
    ``destroy_node`` and ``try_shutdown``. Before ``init`` the DDS transport is chosen
    (:func:`exo_has_runtime.dds.configure_transport`: UDP, not Fast DDS's shared memory). Bad
    DDS settings and bad ROS arguments and a bad configuration (what
    :data:`STARTUP_ERRORS` lists, raised by a constructor) are logged with the node's name and
    end the process with exit code 2, 2 and 1; an error raised while spinning is a bug and keeps
    its traceback.

    Parameters
    ----------
    factories : Sequence[Callable[[], Node]]
        One callable per node, called in order after ``init`` (several: nodes composed in one
        process, as ROS 2 composition does).
    args : Sequence[str] or None
        Command line, ``--ros-args`` included; ``sys.argv`` by default.
    name : str
        Logger name for the errors before a node exists.

    """
    try:
        transport_warning = configure_transport()
    except DdsConfigurationError as exc:
        print(f'[FATAL] [{name}]: cannot start: {exc}', file=sys.stderr)
        raise SystemExit(2) from None
    try:
        rclpy.init(args=list(sys.argv if args is None else args),
                   signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:
        print(f'[FATAL] [{name}]: cannot start: bad ROS arguments: {_first_line(exc)}',
              file=sys.stderr)
        raise SystemExit(2) from None
    nodes: list[Node] = []
    try:
        with _StopOnSignal() as stop:
            try:
                for factory in factories:
                    nodes.append(factory())
            except STARTUP_ERRORS as exc:
                rclpy.logging.get_logger(name).fatal(f'cannot start: {exc}')
                raise SystemExit(1) from None
            if transport_warning and nodes:
                nodes[0].get_logger().warning(transport_warning)
            freeze_startup_objects()
            spin(nodes, stop=stop)
            # The executor is shut down: destroy the nodes while the context is still valid.
            for node in reversed(nodes):
                node.destroy_node()
            nodes.clear()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in reversed(nodes):
            node.destroy_node()
        try_shutdown()


def freeze_startup_objects() -> bool:
    """Keep what the process made so far out of every later garbage collection.

    Collects once, then freezes the survivors (``gc.freeze``): later collections, full ones
    included, walk only the objects made afterwards. Not where ``EXO_HAS_GC_FREEZE`` is ``0``.
    Returns whether it froze.
    """
    if os.environ.get('EXO_HAS_GC_FREEZE', '1') == '0':
        return False
    gc.collect()
    gc.freeze()
    return True


def run_node(factory: Callable[[], Node], args: Sequence[str] | None = None,
             name: str = 'exo_has') -> None:
    """Run one node as :func:`run_nodes` does."""
    run_nodes([factory], args, name)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__

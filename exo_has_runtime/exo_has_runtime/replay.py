"""``exo-has replay BAG``: publish a bag's messages again, as recorded, at a chosen rate.

Each message's CDR bytes go out unchanged on its topic (rclpy publishes ``bytes`` as a
serialized message, never deserialised here), at its bag time since the first replayed message
divided by ``--rate``, measured on the steady clock; each topic is published with the QoS its
bag recorded (:func:`exo_has_runtime.recording.replay_qos`). A 1 ms timer does the publishing,
so messages leave up to about a millisecond late (more on a loaded machine), never early.
At the end, before it leaves the graph, the replay waits (up to ``ACK_TIMEOUT_S``) for every
reliable subscriber to acknowledge what it was sent: a publisher destroyed right after its
last message can take that message with it (a clean CI run once lost the last of 400).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence
from contextlib import ExitStack
from pathlib import Path

from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher

from exo_has_common.bag import BagMessage, bag_topics, read_messages
from exo_has_common.errors import BagError, UnknownMessageTypeError
from exo_has_runtime.errors import ReplayError
from exo_has_runtime.execution import run_node
from exo_has_runtime.message_types import message_class
from exo_has_runtime.recorder import qos_profile
from exo_has_runtime.recording import (
    check_rate,
    replay_offset_ns,
    replay_qos,
    select_replay_topics,
)

_TICK_S = 0.001  # publishing resolution
ACK_TIMEOUT_S = 2.0  # s: at most this long for the subscribers' acknowledgements at the end


class Replayer(Node):
    """Publish the messages of a bag with their recorded timing scaled by a rate factor.

    Parameters
    ----------
    bag : Path
        The bag directory.
    topics : Sequence[str]
        Its topics to replay (fully qualified).
    rate : float
        Playback speed factor (2 replays twice as fast).
    loop : bool
        Start again at the end, rather than shut down.
    delay_s : float
        Wait this long [s] before the first message.
    wait_for_subscribers : bool
        Start only once every topic has a subscriber.

    Raises
    ------
    ReplayError
        If no topic can be published (their types unknown here).

    """

    def __init__(self, bag: Path, topics: Sequence[str], rate: float, loop: bool = False,
                 delay_s: float = 0.0, wait_for_subscribers: bool = False) -> None:
        super().__init__('replay')
        self._bag = bag
        self._speed = rate
        self._looping = loop
        self._wait_for_subscribers = wait_for_subscribers
        recorded = {topic.topic: topic for topic in bag_topics(bag)}
        self._outputs: dict[str, Publisher] = {}
        for topic in topics:
            try:
                message_type = message_class(recorded[topic].msgtype)
            except UnknownMessageTypeError as exc:  # it leaves its topic out, not the rest
                self.get_logger().warning(f'not replaying {topic}: {exc}')
                continue
            self._outputs[topic] = self.create_publisher(
                message_type, topic, qos_profile(replay_qos(recorded[topic].offered_qos)))
        if not self._outputs:
            msg = f'none of the topics of {bag} can be published here'
            raise ReplayError(msg)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._ready_ns = self._steady.now().nanoseconds + round(delay_s * 1e9)
        self._stack = ExitStack()
        self._messages: Iterator[BagMessage] = iter(())
        self._next: BagMessage | None = None
        self._start_ns: int | None = None
        self._first_ns = 0
        self._published = 0
        self._waiting_logged = False
        self.create_timer(_TICK_S, self._on_tick, clock=self._steady)
        self.get_logger().info(f'replaying {len(self._outputs)} topics of {bag} at rate '
                               f'{rate:g}' + (', looping' if loop else ''))

    def _open(self) -> int:
        """Open the bag at its first message; return the steady time of the replay's start."""
        self._stack.close()
        self._messages = self._stack.enter_context(read_messages(self._bag, self._outputs))
        self._next = next(self._messages, None)
        self._first_ns = self._next.timestamp_ns if self._next is not None else 0
        # After opening, which takes a while: the first message is due now.
        self._start_ns = self._steady.now().nanoseconds
        return self._start_ns

    def _on_tick(self) -> None:
        now_ns = self._steady.now().nanoseconds
        if self._start_ns is None:
            if now_ns < self._ready_ns or not self._subscribed():
                return
            now_ns = self._open()
        assert self._start_ns is not None
        elapsed_ns = now_ns - self._start_ns
        while self._next is not None and elapsed_ns >= replay_offset_ns(
                self._next.timestamp_ns, self._first_ns, self._speed):
            self._outputs[self._next.topic].publish(self._next.data)
            self._published += 1
            self._next = next(self._messages, None)
        if self._next is None:
            if self._looping and self._published:
                self._open()
                return
            self.get_logger().info(f'replayed {self._published} messages')
            unacknowledged = self._wait_for_acknowledgements()
            if unacknowledged:
                self.get_logger().warning(
                    f'not acknowledged within {ACK_TIMEOUT_S:g} s on {", ".join(unacknowledged)}:'
                    ' a subscriber there may miss the last messages')
            # Ends the spinning (run_node then destroys the node).
            self.context.try_shutdown()

    def _wait_for_acknowledgements(self) -> list[str]:
        """Wait for the reliable subscribers' acknowledgements; return the topics still waiting."""
        deadline_ns = self._steady.now().nanoseconds + int(ACK_TIMEOUT_S * 1e9)
        waiting = []
        for topic, publisher in self._outputs.items():
            left_ns = max(0, deadline_ns - self._steady.now().nanoseconds)
            if not publisher.wait_for_all_acked(Duration(nanoseconds=left_ns)):
                waiting.append(topic)
        return waiting

    def _subscribed(self) -> bool:
        if not self._wait_for_subscribers:
            return True
        waiting = [t for t, p in self._outputs.items() if p.get_subscription_count() == 0]
        if waiting and not self._waiting_logged:
            self._waiting_logged = True
            self.get_logger().info(f'waiting for subscribers on {", ".join(waiting)}')
        return not waiting

    def destroy_node(self) -> None:
        """Close the bag and leave the graph."""
        stack = getattr(self, '_stack', None)
        if stack is not None:
            stack.close()
        super().destroy_node()


def build_parser() -> argparse.ArgumentParser:
    """Return the command line's parser (tests parse the documentation's commands with it)."""
    parser = argparse.ArgumentParser(prog='exo-has replay', description=__doc__.splitlines()[0])
    parser.add_argument('bag', help='bag directory')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='speed factor: 2 replays twice as fast (1)')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--topics', nargs='+', default=None, metavar='TOPIC',
                        help='replay only these topics (default: all)')
    parser.add_argument('--delay', type=float, default=0.0,
                        help='seconds to wait before the first message (0)')
    parser.add_argument('--wait-for-subscribers', action='store_true',
                        help='start once every replayed topic has a subscriber')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``exo-has replay BAG [--rate F] [--loop] [--topics T ...] [--delay S]``."""
    parser = build_parser()
    args, ros_args = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    try:
        rate = check_rate(args.rate)
        if not args.delay >= 0.0:
            msg = f'the delay must be zero or positive, got {args.delay}'
            raise ReplayError(msg)
        available = {topic.topic: topic.msgtype for topic in bag_topics(args.bag)}
        topics = select_replay_topics(available, args.topics)
    except (BagError, ReplayError) as exc:
        print(f'exo-has replay: {exc}', file=sys.stderr)
        return 1
    bag = Path(args.bag).expanduser()
    try:
        run_node(lambda: Replayer(bag, topics, rate, args.loop, args.delay,
                                  args.wait_for_subscribers),
                 ['exo-has-replay', *ros_args], name='replay')
    except SystemExit as exc:  # run_node's exit on a bad start: this command returns its code
        return exc.code if isinstance(exc.code, int) else 1
    return 0


if __name__ == '__main__':
    sys.exit(main())

"""``ros2 topic echo`` and ``pub`` for raw CDR, as a process: record messages, publish given ones.

ros2cli is not on PyPI; sessions on two hosts, the transport tests and the benches use this.

``python -m exo_has_runtime.topic_tool record TOPIC=TYPE ... [--qos ...] [--count N]``
prints one JSON line per message received (``{"topic": ..., "cdr": <hex>}``) and ``READY`` once
subscribed. ``... publish TOPIC=TYPE=JSON ...`` publishes each message (fields as JSON) once a
subscriber matched (or at once with ``--no-wait``), then every ``--period`` seconds, for
``--duration`` seconds (or ``--count`` rounds, then waits until every reliable reader
acknowledged them and prints ``ACKED``, or ``NOT ACKED`` at the end of the duration).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from exo_has_common.errors import UnknownMessageTypeError
from exo_has_runtime.message_types import message_class


def fill_message(message: Any, fields: Mapping[str, Any]) -> Any:
    """Set a message's fields from a mapping, recursing into nested messages."""
    for name, value in fields.items():
        current = getattr(message, name)
        if isinstance(value, Mapping):
            fill_message(current, value)
        elif isinstance(value, list) and value and isinstance(value[0], Mapping):
            item_type = type(current[0]) if current else None
            if item_type is None:
                nested = message.get_fields_and_field_types()[name]
                item_type = message_class(nested.split('<', 1)[-1].split(',')[0].rstrip('>'))
            setattr(message, name, [fill_message(item_type(), item) for item in value])
        else:
            setattr(message, name, value)
    return message


def _qos(text: str) -> QoSProfile:
    reliability, durability, depth = [*text.split(','), '', '', ''][:3]
    return QoSProfile(
        depth=int(depth or 10),
        reliability=ReliabilityPolicy[(reliability or 'reliable').upper()],
        durability=DurabilityPolicy[(durability or 'volatile').upper()])


def record(node: Node, specs: Sequence[str], qos: QoSProfile, count: int,
           duration_s: float) -> None:
    """Print received messages as JSON lines until ``count`` arrived or time is up."""
    received = 0

    def callback_for(topic: str) -> Any:
        def on_message(data: bytes) -> None:
            nonlocal received
            received += 1
            print(json.dumps({'topic': topic, 'cdr': bytes(data).hex()}), flush=True)
        return on_message

    for spec in specs:
        topic, type_name = spec.split('=', 1)
        node.create_subscription(message_class(type_name), topic, callback_for(topic), qos,
                                 raw=True)
    print('READY', flush=True)
    deadline = time.monotonic() + duration_s
    while (count <= 0 or received < count) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)


def publish(node: Node, specs: Sequence[str], qos: QoSProfile, wait: bool, period_s: float,
            duration_s: float, count: int = 0) -> None:
    """Publish the given messages, repeating every ``period_s``, ``count`` times (0: no end)."""
    items = []
    for spec in specs:
        topic, type_name, fields = spec.split('=', 2)
        message_type = message_class(type_name)
        publisher = node.create_publisher(message_type, topic, qos)
        items.append((publisher, fill_message(message_type(), json.loads(fields))))
    print('READY', flush=True)
    deadline = time.monotonic() + duration_s
    while wait and any(p.get_subscription_count() == 0 for p, _ in items):
        if time.monotonic() > deadline:
            return
        rclpy.spin_once(node, timeout_sec=0.02)
    published = 0
    while True:
        for publisher, message in items:
            publisher.publish(message)
        print('PUBLISHED', flush=True)
        published += 1
        if published == count:
            # A reliable message may need resending (a lossy link, a reader matching late):
            # leave only once every reader acknowledged it, or the time is up.
            left = Duration(nanoseconds=max(0, int((deadline - time.monotonic()) * 1e9)))
            acked = all(p.wait_for_all_acked(left) for p, _ in items
                        if p.qos_profile.reliability == ReliabilityPolicy.RELIABLE)
            print('ACKED' if acked else 'NOT ACKED', flush=True)
            return
        end = time.monotonic() + period_s
        while time.monotonic() < min(end, deadline):
            rclpy.spin_once(node, timeout_sec=0.02)
        if time.monotonic() >= deadline:
            return


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments and run the peer."""
    parser = argparse.ArgumentParser(prog='peers')
    parser.add_argument('role', choices=('record', 'publish'))
    parser.add_argument('specs', nargs='+', help='TOPIC=TYPE (record) or TOPIC=TYPE=JSON')
    parser.add_argument('--qos', default='reliable,volatile,10',
                        help='RELIABILITY,DURABILITY,DEPTH')
    parser.add_argument('--count', type=int, default=0,
                        help='record: stop after N messages; publish: after N rounds')
    parser.add_argument('--duration', type=float, default=10.0, help='seconds to run')
    parser.add_argument('--period', type=float, default=3600.0, help='publish: repeat period')
    parser.add_argument('--no-wait', action='store_true', help='publish: do not wait for match')
    parser.add_argument('--name', default='peer', help='node name')
    args, ros_args = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    rclpy.init(args=['peers', *ros_args])
    node = Node(args.name)
    try:
        if args.role == 'record':
            record(node, args.specs, _qos(args.qos), args.count, args.duration)
        else:
            publish(node, args.specs, _qos(args.qos), not args.no_wait, args.period,
                    args.duration, args.count)
    except UnknownMessageTypeError as exc:
        print(f'peers: {exc}', file=sys.stderr, flush=True)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())

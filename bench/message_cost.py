"""Benchmark: CPU per HasState published and received between two rclpy processes.

A publisher process sends four joints' ``HasState`` at 200 Hz each (800 messages a second, as
the plants do) with ``qos_profile_sensor_data``; a subscriber process takes them on the
events executor (:mod:`exo_has_runtime.execution`), typed or raw (serialized). After 4 s of
warm-up each process measures its own CPU time (``time.process_time``, every thread) over
10 s and divides by the messages of that window: the cost of one message on each side.

Run (in ``./run shell``): ``python bench/message_cost.py`` (printout and
``bench/results/message_cost.{json,txt}``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

from common import describe_machine, on_this_machine, write_results

from exo_has_runtime.processes import Processes

JOINTS = ('left_hip', 'left_knee', 'right_hip', 'right_knee')
WARM_UP_S, WINDOW_S = 4.0, 10.0


def side(role: str, raw: bool) -> None:
    """Publish or receive for the warm-up and the window; print CPU and messages as JSON."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from exo_has_msgs.msg import HasState
    from exo_has_runtime.execution import spin

    rclpy.init()
    node = Node(f'message_cost_{role}')
    count = [0]
    if role == 'publish':
        publishers = [node.create_publisher(HasState, f'{j}/has_state', qos_profile_sensor_data)
                      for j in JOINTS]

        def tick() -> None:
            stamp = node.get_clock().now().to_msg()
            for joint, publisher in zip(JOINTS, publishers, strict=True):
                message = HasState(joint=joint, position=0.1)
                message.header.stamp = stamp
                publisher.publish(message)
                count[0] += 1
        node.create_timer(0.005, tick)
    else:
        def take(_message: object) -> None:
            count[0] += 1
        for joint in JOINTS:
            node.create_subscription(HasState, f'{joint}/has_state', take,
                                     qos_profile_sensor_data, raw=raw)
    stop = threading.Event()
    result: dict[str, float] = {}

    def measure() -> None:
        time.sleep(WARM_UP_S)
        cpu, messages = time.process_time(), count[0]
        time.sleep(WINDOW_S)
        result['cpu_s'] = time.process_time() - cpu
        result['messages'] = count[0] - messages
        stop.set()
    threading.Thread(target=measure, daemon=True).start()
    spin(node, stop=stop)
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps(result), flush=True)


def pair(raw: bool) -> dict[str, float]:
    """Run a publisher and a subscriber side by side; the cost per message of each [us]."""
    here = str(Path(__file__).resolve())
    with Processes() as processes:
        sides = {role: processes.start([sys.executable, here, '_side', role, str(raw)],
                                       stdout=subprocess.PIPE, text=True)
                 for role in ('publish', 'receive')}
        out = {role: json.loads(p.communicate(timeout=120)[0].strip().splitlines()[-1])
               for role, p in sides.items()}
    return {f'{role}_us': round(1e6 * r['cpu_s'] / max(r['messages'], 1), 1)
            for role, r in out.items()} | {'received': out['receive']['messages']}


def main() -> None:
    """Measure typed and raw reception, three runs each, and write the results."""
    if len(sys.argv) > 1 and sys.argv[1] == '_side':
        side(sys.argv[2], sys.argv[3] == 'True')
        return
    on_this_machine()
    runs = [{'raw': raw, **pair(raw)} for _ in range(3) for raw in (False, True)]
    lines = [f'bench/message_cost.py: {describe_machine()}']
    for raw in (False, True):
        chosen = sorted(runs, key=lambda r: r['receive_us'])
        chosen = [r for r in chosen if r['raw'] == raw]
        median = chosen[len(chosen) // 2]
        lines.append(f'{"raw" if raw else "typed"} subscription, median of {len(chosen)}: '
                     f'receive {median["receive_us"]} us, publish {median["publish_us"]} us '
                     f'per message (runs: {chosen})')
    write_results('message_cost', {'runs': runs}, lines)


if __name__ == '__main__':
    main()

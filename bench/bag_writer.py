"""Benchmark: writing a rosbag2 MCAP bag with the ``mcap`` package against rosbags' writer.

Both write the same bag: 50 000 ``HasState`` messages (CDR from
``rclpy.serialization.serialize_message``) round-robin on four topics, as four joints' states,
each a ``ros2msg`` schema and a ``cdr`` channel, with the file flushed as a complete chunk
every ``--flush-every`` messages, as the recorder does every second; then the summary and
footer. The clock runs from opening the file to closing it. ``mcap`` flushes with its public
``Writer.flush()``; rosbags has no public way to close a chunk early, so its variant calls
``McapWriter.close_chunk()``, an internal. ``BagWriter`` is what the recorder ships: the
``mcap`` writer on a thread of its own, which takes the queued messages in batches, with
``metadata.yaml``; its time includes handing each message over and waiting for the thread to
finish. Results: ``bench/results/bag_writer.txt`` and ``.json``.

Usage: ``.venv/bin/python bench/bag_writer.py [--messages N] [--repeats N] [--out FILE]``
(with the workspace sourced: ``source install/setup.bash``).
"""

from __future__ import annotations

import argparse
import gc
import json
import random
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from common import describe_machine
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as RosbagsWriter
from rosbags.rosbag2.storage_mcap import McapWriter as RosbagsMcapStorage

from exo_has_common.bag import BagWriter, message_definition
from exo_has_msgs.msg import HasState

TYPE = 'exo_has_msgs/msg/HasState'
TOPICS = [f'/{joint}/has_state' for joint in ('left_hip', 'left_knee', 'right_hip',
                                               'right_knee')]
T0_NS = 1_700_000_000_000_000_000

Messages = list[tuple[str, int, bytes]]


def make_messages(count: int) -> Messages:
    """Return ``count`` (topic, time [ns], CDR) of distinct HasStates, 200 Hz per topic."""
    messages = []
    for i in range(count):
        topic = TOPICS[i % len(TOPICS)]
        state = HasState(joint=topic.split('/')[1], position=0.05 + i * 1e-7,
                         velocity=0.01, pressure_a=4.0e6 + i, pressure_b=1.5e5,
                         motor_speed=100.0, motor_speed_command=101.0, motor_current=2.5,
                         load_force=-250.0)
        state.header.stamp.sec, state.header.stamp.nanosec = divmod(i * 1_250_000, 10**9)
        messages.append((topic, T0_NS + i * 1_250_000, serialize_message(state)))
    return messages


def write_mcap(path: Path, messages: Messages, flush_every: int, compress: bool) -> None:
    """Write with the ``mcap`` package's writer."""
    definition, type_hash = message_definition(TYPE)
    path.mkdir()
    with (path / f'{path.name}.mcap').open('wb') as stream:
        writer = McapWriter(stream, compression=CompressionType.ZSTD if compress
                            else CompressionType.NONE)
        writer.start(profile='ros2', library='bench')
        schema = writer.register_schema(TYPE, 'ros2msg', definition.encode())
        channels = {topic: writer.register_channel(topic, 'cdr', schema, {
            'offered_qos_profiles': '', 'topic_type_hash': type_hash}) for topic in TOPICS}
        for i, (topic, stamp, data) in enumerate(messages):
            writer.add_message(channels[topic], stamp, data, stamp)
            if (i + 1) % flush_every == 0:
                writer.flush()
        writer.finish()


def write_rosbags(path: Path, messages: Messages, flush_every: int, compress: bool) -> None:
    """Write with rosbags' rosbag2 writer (MCAP storage)."""
    definition, type_hash = message_definition(TYPE)
    writer = RosbagsWriter(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {topic: writer.add_connection(topic, TYPE, msgdef=definition,
                                                    rihs01=type_hash) for topic in TOPICS}
        storage = writer.storage
        assert isinstance(storage, RosbagsMcapStorage)
        for i, (topic, stamp, data) in enumerate(messages):
            writer.write(connections[topic], stamp, data)
            if (i + 1) % flush_every == 0:
                storage.close_chunk()
                storage.bio.flush()


def write_shipped(path: Path, messages: Messages, flush_every: int, compress: bool) -> None:
    """Write with :class:`exo_has_common.bag.BagWriter`, as the recorder does."""
    with BagWriter(path, compress=compress) as writer:
        for topic in TOPICS:
            writer.add_topic(topic, TYPE)
        for i, (topic, stamp, data) in enumerate(messages):
            writer.write(topic, stamp, data)
            if (i + 1) % flush_every == 0:
                writer.flush()


WRITERS: dict[str, Callable[[Path, Messages, int, bool], None]] = {
    'mcap': write_mcap, 'rosbags': write_rosbags, 'BagWriter (mcap, thread)': write_shipped}


def main() -> None:
    """Time each writer, uncompressed and zstd, side by side; print the medians."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--messages', type=int, default=50_000, help='messages per bag (50000)')
    parser.add_argument('--flush-every', type=int, default=1000,
                        help='messages between two flushes (1000)')
    parser.add_argument('--repeats', type=int, default=9, help='runs per writer (9)')
    parser.add_argument('--out', type=Path, help='write the results as JSON here')
    args = parser.parse_args()
    messages = make_messages(args.messages)
    times: dict[str, list[float]] = {}
    sizes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as root:
        variants = [(name, compress) for compress in (False, True) for name in WRITERS]
        for key in (f'{n}, {"zstd" if c else "uncompressed"}' for n, c in variants):
            times[key] = []
        for run in range(args.repeats):
            # Interleaved in a new order each run, so that neither a slow spell of the shared
            # machine nor the order (the garbage collector's state) favours one writer.
            random.Random(run).shuffle(variants)
            for name, compress in variants:
                key = f'{name}, {"zstd" if compress else "uncompressed"}'
                path = Path(root, f'{run}_{compress}_{name[:4]}')
                gc.collect()
                start = time.perf_counter()
                WRITERS[name](path, messages, args.flush_every, compress)
                times[key].append(time.perf_counter() - start)
                sizes[key] = sum(f.stat().st_size for f in path.glob('*.mcap'))
    print(f'{args.messages} HasState messages on {len(TOPICS)} topics, a chunk every '
          f'{args.flush_every} messages; median of {args.repeats} runs')
    print(f'{"writer":<40} {"median [s]":>10} {"per message [us]":>17} {"file [kB]":>10}')
    results = {}
    for key, runs in times.items():
        median = statistics.median(runs)
        results[key] = {'median_s': median, 'runs_s': runs, 'file_bytes': sizes[key],
                        'per_message_us': median / args.messages * 1e6}
        print(f'{key:<40} {median:10.3f} {median / args.messages * 1e6:17.2f} '
              f'{sizes[key] / 1e3:10.0f}')
    if args.out is not None:
        args.out.write_text(json.dumps({'machine': describe_machine(),
                                        'messages': args.messages,
                                        'flush_every': args.flush_every,
                                        'repeats': args.repeats, 'results': results},
                                       indent=2) + '\n')


if __name__ == '__main__':
    main()

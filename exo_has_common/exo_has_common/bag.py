"""Bags (rosbag2, MCAP storage, metadata version 9): their public names and ``exo-has bag``.

The work is done by the modules of :mod:`exo_has_common.bags`, one per task: message
definitions, offered QoS, writing, reading, reading a killed writer's file record by record, and
recovery. This module gathers their public names (``from exo_has_common.bag import
BagWriter, read_messages, recover_bag``) and runs ``exo-has bag info BAG`` and ``exo-has bag
recover BAG``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from exo_has_common.bags.definitions import (
    default_typestore,
    ensure_message_type,
    message_definition,
    msg_file,
    normalize_type_name,
)
from exo_has_common.bags.qos import QosProfileLike, offered_qos
from exo_has_common.bags.reader import (
    BagMessage,
    BagSummary,
    BagTopic,
    TopicSummary,
    bag_summary,
    bag_topics,
    bag_typestore,
    format_summary,
    read_messages,
)
from exo_has_common.bags.records import MCAP_MAGIC, McapRecordReader
from exo_has_common.bags.recovery import RecoveryReport, recover_bag
from exo_has_common.bags.writer import BagWriter, Rosbag2Writer
from exo_has_common.errors import BagError

__all__ = [
    'MCAP_MAGIC', 'BagMessage', 'BagSummary', 'BagTopic', 'BagWriter', 'McapRecordReader',
    'QosProfileLike', 'RecoveryReport', 'Rosbag2Writer', 'TopicSummary', 'bag_summary',
    'bag_topics', 'bag_typestore', 'build_parser', 'default_typestore', 'ensure_message_type',
    'format_summary', 'main', 'message_definition', 'msg_file', 'normalize_type_name',
    'offered_qos', 'read_messages', 'recover_bag',
]


def build_parser() -> argparse.ArgumentParser:
    """Return the command line's parser (tests parse the documentation's commands with it)."""
    parser = argparse.ArgumentParser(prog='exo-has bag', description='Inspect and recover bags.')
    actions = parser.add_subparsers(dest='action', required=True, metavar='ACTION')
    info = actions.add_parser('info', help='topics, types, counts, duration and rates of a bag')
    info.add_argument('bag', help='bag directory')
    recover = actions.add_parser(
        'recover', help='rewrite a bag whose recorder was killed, up to its last complete chunk')
    recover.add_argument('bag', help='bag directory (or .mcap file)')
    recover.add_argument('--output', '-o', default=None,
                         help='new bag directory (default: in place, originals kept as *.orig)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``exo-has bag info BAG`` or ``exo-has bag recover BAG [--output DIR]``."""
    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if args.action == 'info':
            print(format_summary(bag_summary(args.bag)))
        else:
            print(recover_bag(args.bag, args.output).describe())
    except BagError as exc:
        print(f'exo-has bag {args.action}: {exc}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())

"""A stand-in for the bridge's input side: constant joint references to the robot loop.

``python robot_reference_sender.py SOCKET_DIR RATE JOINT=ANGLE ...`` sends a
:class:`~exo_has_bringup.robot_messages.Reference` (angles [rad], rates 0) and a
:class:`~exo_has_bringup.robot_messages.BridgeStatus` (the publisher present) at RATE [Hz] to
the loop's socket in SOCKET_DIR until killed; prints ``sending`` once it runs.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from exo_has_bringup.robot_exchange import LOOP_SOCKET, DatagramExchange
from exo_has_bringup.robot_messages import BridgeStatus, Reference


def main(argv: list[str]) -> None:
    directory, rate, *pairs = argv
    names = tuple(pair.split('=')[0] for pair in pairs)
    angles = tuple(float(pair.split('=')[1]) for pair in pairs)
    own = Path(directory) / f'sender-{os.getpid()}.sock'
    exchange = DatagramExchange(own, Path(directory) / LOOP_SOCKET, ())
    period = 1.0 / float(rate)
    print('sending', flush=True)
    try:
        while True:
            exchange.send(Reference(time.monotonic(), names, angles, (0.0,) * len(names)))
            exchange.send(BridgeStatus(True))
            time.sleep(period)
    finally:
        exchange.close()


if __name__ == '__main__':
    main(sys.argv[1:])

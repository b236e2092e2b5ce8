"""``exo-has demo``: run the two demonstration nodes as separate processes and report.

Until the exoskeleton session exists (issue 4), the main job shows the runtime at work: the
state echo and the command talker start as two processes, exchange HAS commands and states
for every joint over DDS, and the talker's round-trip statistics are shown as it runs.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence


def run_demo(duration_s: float, rate_hz: float) -> int:
    """Start the echo, then the talker for ``duration_s``; stream the talker's log.

    Returns
    -------
    int
        The talker's exit code (0 when it ran to the end).

    """
    python = sys.executable
    # -m puts the working directory on sys.path, where a workspace's package folders would
    # shadow the installed packages: run the nodes from a neutral folder.
    neutral = tempfile.gettempdir()
    echo = subprocess.Popen([python, '-m', 'exo_has_runtime.demo.state_echo'], cwd=neutral)
    try:
        time.sleep(0.5)  # let the echo subscribe so the first commands are answered
        talker = subprocess.run(
            [python, '-m', 'exo_has_runtime.demo.command_talker', '--ros-args',
             '-p', f'duration:={float(duration_s)}', '-p', f'rate:={float(rate_hz)}'],
            check=False, cwd=neutral)
    finally:
        echo.terminate()
        echo.wait(timeout=10)
    return talker.returncode


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments and run the demonstration."""
    parser = argparse.ArgumentParser(prog='exo-has demo', description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=5.0, help='seconds to run (5)')
    parser.add_argument('--rate', type=float, default=200.0, help='command rate in Hz (200)')
    args = parser.parse_args(argv)
    print(f'exo-has demo: state echo and command talker, 4 joints at {args.rate:g} Hz '
          f'for {args.duration:g} s', flush=True)
    code = run_demo(args.duration, args.rate)
    print('exo-has demo: done' if code == 0 else f'exo-has demo: talker exited with {code}')
    return code


if __name__ == '__main__':
    sys.exit(main())

"""Run a Python module as a child process that ends when the process that started it ends.

``python -m exo_has_runtime.testing.tether PARENT_PID MODULE ARGS...`` asks Linux to send the
process SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``), checks that the parent is
still ``PARENT_PID`` (it may have died before the request took effect), then runs ``MODULE`` as
``python -m`` would, with ``ARGS``. A node ends on SIGTERM as on SIGINT (its bag closed, its
last words logged), so a session whose runner is killed, even by SIGKILL, leaves no node
behind. This is done in the child rather than in a ``preexec_fn`` because the runner may have
threads (an rclpy observer in a test), and ``subprocess`` warns that ``preexec_fn`` is unsafe
then.

Linux sends the signal when the thread that forked the child ends, not the whole process: a
session must be started from a thread that lives as long as the session (the main thread, in
``exo-has demo`` and the tests).
"""

from __future__ import annotations

import ctypes
import os
import runpy
import signal
import sys

#: ``PR_SET_PDEATHSIG`` from ``<linux/prctl.h>``.
PR_SET_PDEATHSIG = 1

#: Exit code when the parent was already gone: as a process ended by SIGTERM reports it.
ORPHANED_EXIT = 128 + signal.SIGTERM


def tie_to_parent(parent_pid: int) -> None:
    """Have Linux send this process SIGTERM when its parent dies.

    Raises
    ------
    OSError
        If the kernel refuses the request.
    SystemExit
        With :data:`ORPHANED_EXIT`, if the parent is no longer ``parent_pid``.

    """
    if sys.platform.startswith('linux'):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            errno = ctypes.get_errno()
            msg = f'prctl(PR_SET_PDEATHSIG) failed: {os.strerror(errno)}'
            raise OSError(errno, msg)
    if os.getppid() != parent_pid:
        print(f'tether: parent {parent_pid} ended before this process started; not running',
              file=sys.stderr)
        raise SystemExit(ORPHANED_EXIT)


def main() -> None:
    """Tie this process to its parent, then run the module with its arguments."""
    if len(sys.argv) < 3 or not sys.argv[1].isdigit():
        sys.exit('usage: python -m exo_has_runtime.testing.tether PARENT_PID MODULE [ARGS...]')
    tie_to_parent(int(sys.argv[1]))
    module = sys.argv[2]
    sys.argv = [module, *sys.argv[3:]]
    runpy.run_module(module, run_name='__main__', alter_sys=True)


if __name__ == '__main__':
    main()

"""Run a Python module as a child process that ends when the process that started it ends.

``python -m exo_has_runtime.tether PARENT_PID MODULE ARGS...`` asks Linux to send the
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

``--netns PATH`` before ``MODULE`` runs it in the network namespace at ``PATH``
(``/proc/<pid>/ns/net``); ``--netns new`` in a new, empty one. It is entered here, before the
module starts a thread (``setns`` and ``unshare`` act on the calling thread, and rclpy's
threads inherit it), which is why Python 3.11, without ``os.setns``, calls libc. A namespace
made so lives as long as a process in it: when the runner dies, its tethered processes end and
the namespace goes with them (:mod:`exo_has_bringup.hosts`).

``--exec COMMAND ARGS...`` in place of ``MODULE`` runs a program instead (``execvp``): the
request outlives the exec (not into a set-user-ID program), so that a benchmark's spinners and
tools (``taskset``, ``cyclictest``) end with it too (``bench/common.py``).
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

#: ``CLONE_NEWNET`` from ``<sched.h>``.
CLONE_NEWNET = 0x40000000

#: Exit code when the network namespace could not be entered.
NETNS_EXIT = 3

#: Exit code when the program of ``--exec`` could not be run: as a shell reports it.
EXEC_EXIT = 127


def enter_network_namespace(path: str) -> None:
    """Move this (single-threaded) process into the network namespace at ``path``, or a new one.

    Raises
    ------
    OSError
        If the namespace cannot be opened or entered (it needs CAP_SYS_ADMIN: root).

    """
    libc = ctypes.CDLL(None, use_errno=True)
    if path == 'new':
        if libc.unshare(CLONE_NEWNET) != 0:
            errno = ctypes.get_errno()
            raise OSError(errno, f'unshare(CLONE_NEWNET) failed: {os.strerror(errno)}')
        return
    descriptor = os.open(path, os.O_RDONLY)
    try:
        if libc.setns(descriptor, CLONE_NEWNET) != 0:
            errno = ctypes.get_errno()
            raise OSError(errno, f'setns({path}) failed: {os.strerror(errno)}')
    finally:
        os.close(descriptor)


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
    """Tie this process to its parent, then run the module (or program) with its arguments."""
    usage = ('usage: python -m exo_has_runtime.tether PARENT_PID [--netns PATH|new] '
             '(MODULE | --exec COMMAND) [ARGS...]')
    if len(sys.argv) < 3 or not sys.argv[1].isdigit():
        sys.exit(usage)
    tie_to_parent(int(sys.argv[1]))
    rest = sys.argv[2:]
    if rest[0] == '--netns':
        if len(rest) < 3:
            sys.exit(usage)
        try:
            enter_network_namespace(rest[1])
        except OSError as exc:
            print(f'tether: cannot enter the network namespace {rest[1]}: {exc.strerror}',
                  file=sys.stderr)
            raise SystemExit(NETNS_EXIT) from None
        rest = rest[2:]
    if rest[0] == '--exec':
        if len(rest) < 2:
            sys.exit(usage)
        try:
            os.execvp(rest[1], rest[1:])
        except OSError as exc:
            print(f'tether: cannot run {rest[1]}: {exc.strerror}', file=sys.stderr)
            raise SystemExit(EXEC_EXIT) from None
    module = rest[0]
    sys.argv = [module, *rest[1:]]
    runpy.run_module(module, run_name='__main__', alter_sys=True)


if __name__ == '__main__':
    main()

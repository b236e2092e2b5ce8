"""Start nodes as separate processes for tests, without launch files.

A :class:`NodeProcess` runs ``python -m MODULE ARGS...`` with its output in a file, can wait for
a line of that output, and stops the process as ``ros2 launch`` would: SIGINT, then SIGTERM,
then SIGKILL. The process is tied to the one that started it
(:mod:`exo_has_runtime.tether`): it gets SIGTERM when its starter dies, however that
dies, so no node outlives the session or test that owns it. It runs in a session (and process
group) of its own, so that a terminal's Ctrl-C or hang-up reaches only the owner, which stops
its nodes in order.

:class:`Processes` does the same for any command (``taskset``, ``cyclictest``, a spinning
``python -c``): the benchmarks' processes and the tests' own.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any


class NodeProcess:
    """A node (or any Python module) running in its own process.

    Parameters
    ----------
    module : str
        Module run with ``python -m``.
    args : Sequence[str]
        Its arguments.
    env : Mapping[str, str] or None
        Extra environment variables.
    log_path : Path or None
        File for the output; a new temporary file by default.
    stdin : bool
        Whether to keep a pipe to the process's standard input for :meth:`send` (a simulated
        device's fault injection, say); otherwise it reads /dev/null.
    netns : str or None
        Network namespace to run in (``/proc/<pid>/ns/net``, or ``new``); None: this one.

    """

    def __init__(self, module: str, args: Sequence[str] = (),
                 env: Mapping[str, str] | None = None, log_path: Path | None = None,
                 stdin: bool = False, netns: str | None = None) -> None:
        self.module = module
        # Kept open while the process runs; closed by stop().
        self._log: IO[bytes]
        if log_path is None:
            self._log = tempfile.NamedTemporaryFile(
                prefix=module.rsplit('.', 1)[-1] + '-', suffix='.log', delete=False)
        else:
            self._log = Path(log_path).open('wb')
        self.log_path = Path(self._log.name)
        if log_path is None:
            # Readable (``output``) for as long as this object lives, then removed: a test
            # suite starts thousands of processes and would leave each one's log behind.
            weakref.finalize(self, self.log_path.unlink, missing_ok=True)
        self.process = subprocess.Popen(
            [sys.executable, '-u', '-m', 'exo_has_runtime.tether', str(os.getpid()),
             *(('--netns', netns) if netns is not None else ()), module, *args],
            stdout=self._log, start_new_session=True,
            stderr=subprocess.STDOUT, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            text=stdin,
            env={**os.environ, **(env or {})},
            # -m puts the working directory first on sys.path; in a workspace root the package
            # folders would shadow the installed packages, so run from a neutral folder.
            cwd=tempfile.gettempdir())

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    @property
    def output(self) -> str:
        """Everything the process wrote so far (stdout and stderr)."""
        return self.log_path.read_text(encoding='utf-8', errors='replace')

    def wait_for_output(self, pattern: str, timeout_s: float = 10.0) -> re.Match[str]:
        """Wait until the output matches a regular expression.

        Raises
        ------
        TimeoutError
            If it does not within the timeout, or the process ends first; the output is quoted.

        """
        deadline = time.monotonic() + timeout_s
        compiled = re.compile(pattern)
        while True:
            match = compiled.search(self.output)
            if match:
                return match
            if self.process.poll() is not None or time.monotonic() > deadline:
                state = (f'exited with {self.process.returncode}'
                         if self.process.poll() is not None else f'no match in {timeout_s} s')
                msg = f'{self.module}: {state} waiting for {pattern!r}; output:\n{self.output}'
                raise TimeoutError(msg)
            time.sleep(0.02)

    def runs_at_realtime_priority(self, priority: int) -> bool:
        """Whether the main thread runs under ``SCHED_FIFO`` at ``priority``.

        Where the process said it had no permission for it (exo_has_common.realtime), whether
        it runs under the default scheduler instead.
        """
        pid = self.process.pid
        if 'no permission' in self.output:
            return os.sched_getscheduler(pid) == os.SCHED_OTHER
        return (os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority) == (
            os.SCHED_FIFO, priority)

    def send(self, line: str) -> None:
        """Write a line to the process's standard input.

        Raises
        ------
        RuntimeError
            If the process was started without ``stdin``, or has ended.

        """
        pipe = self.process.stdin
        if pipe is None:
            msg = f'{self.module} was started without a pipe to its standard input'
            raise RuntimeError(msg)
        if self.process.poll() is not None:
            msg = f'{self.module} has ended (exit code {self.process.returncode}): cannot send'
            raise RuntimeError(msg)
        pipe.write(line.rstrip('\n') + '\n')
        pipe.flush()

    def wait(self, timeout_s: float = 10.0) -> int:
        """Wait for the process to end on its own and return its exit code."""
        return self.process.wait(timeout=timeout_s)

    def stop(self, timeout_s: float = 5.0) -> int:
        """Stop the process (SIGINT, SIGTERM, then SIGKILL) and return its exit code."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if self.process.poll() is not None:
                break
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                continue
        self._log.close()
        if self.process.stdin is not None:
            self.process.stdin.close()
        return self.process.wait()

    def kill(self) -> None:
        """End the process at once (SIGKILL), as a crash would."""
        self.process.kill()
        self.process.wait()


#: How long [s] the processes of :class:`Processes` have to end on their first signal.
GRACE = 5.0


def tethered(command: Sequence[str]) -> list[str]:
    """Return ``command`` run so that it gets SIGTERM when this process dies, even by SIGKILL.

    Through :mod:`exo_has_runtime.tether` (``--exec``): Linux signals it when the thread that
    started it ends, so start it from a thread that outlives it (the main thread).
    """
    return [sys.executable, '-m', 'exo_has_runtime.tether', str(os.getpid()), '--exec',
            *command]


class Processes:
    """Processes of any command (a benchmark's), each ended however the ``with`` closes.

    Each runs tethered (:func:`tethered`: it ends with this process, even one killed by
    SIGKILL) in a session and process group of its own (a terminal's Ctrl-C reaches only the
    owner, which ends them here). On exit, normal or by an exception (a set-up step that
    failed, KeyboardInterrupt), every process still running gets SIGTERM with its group, then
    SIGKILL after ``grace`` seconds, and is reaped.

    Parameters
    ----------
    grace : float
        Time [s] to end on SIGTERM before SIGKILL.

    """

    def __init__(self, grace: float = GRACE) -> None:
        self.grace = grace
        self.started: list[subprocess.Popen[Any]] = []

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.end(*self.started)

    def start(self, command: Sequence[str], **options: Any) -> subprocess.Popen[Any]:
        """Start ``command`` (options as :class:`subprocess.Popen` takes them); return it."""
        process = subprocess.Popen(tethered(command), start_new_session=True, **options)
        self.started.append(process)
        return process

    def run(self, command: Sequence[str], timeout: float | None = None, check: bool = False,
            **options: Any) -> subprocess.CompletedProcess[Any]:
        """Run ``command`` to its end, as :func:`subprocess.run` would, and return what it gave.

        Its output is captured where ``options`` say (``stdout=subprocess.PIPE``...). Past
        ``timeout`` [s], :class:`subprocess.TimeoutExpired`; with ``check``, an exit code
        other than 0 raises :class:`subprocess.CalledProcessError`. Either way, and on any
        other exception, the process is ended when the ``with`` closes.
        """
        process = self.start(command, **options)
        stdout, stderr = process.communicate(timeout=timeout)
        if check and process.returncode != 0:
            raise subprocess.CalledProcessError(process.returncode, list(command), stdout,
                                                stderr)
        return subprocess.CompletedProcess(list(command), process.returncode, stdout, stderr)

    def end(self, *processes: subprocess.Popen[Any], first: int = signal.SIGTERM) -> None:
        """End ``processes`` and their groups: ``first``, then SIGKILL after the grace time."""
        running = [p for p in processes if p.returncode is None]
        for process in running:
            signal_group(process, first)
        deadline = time.monotonic() + self.grace
        for process in running:
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                signal_group(process, signal.SIGKILL)
                process.wait()


def signal_group(process: subprocess.Popen[Any], number: int) -> None:
    """Send signal ``number`` to the process group that ``process`` (not yet reaped) leads."""
    # Until it is reaped, its id is its group's and no other process's.
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, number)


def stat_fields(pid: int) -> list[str]:
    """Return the fields of ``/proc/<pid>/stat`` after the name: state, parent, ..., flags at 6.

    Raises
    ------
    OSError
        If there is no such process.

    """
    return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()


def alive(pid: int) -> bool:
    """Whether a process exists and has not ended (a zombie, ended but not reaped, has)."""
    try:
        return stat_fields(pid)[0] != 'Z'
    except OSError:
        return False


def children(parent: int | None = None, zombies: bool = False) -> dict[int, str]:
    """Return the children of ``parent`` (default this process): pid to command line.

    Those that ended but were not reaped (zombies) only with ``zombies``.
    """
    parent = os.getpid() if parent is None else parent
    found = {}
    for entry in Path('/proc').glob('[0-9]*'):
        with contextlib.suppress(OSError, IndexError):  # ended meanwhile
            fields = stat_fields(int(entry.name))
            if int(fields[1]) == parent and (zombies or fields[0] != 'Z'):
                command = (entry / 'cmdline').read_bytes().replace(b'\0', b' ')
                found[int(entry.name)] = command.decode(errors='replace').strip()
    return found

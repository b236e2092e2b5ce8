"""Diagnosing many records: on worker processes of this machine, or on a Dask cluster.

:func:`run_batch` diagnoses records (:mod:`~exo_has_sim.diagnosis.records`) into a summary
folder (:mod:`~exo_has_sim.diagnosis.summary`), each record by
:func:`~exo_has_sim.diagnosis.records.diagnose_record`, the unit of work, wherever it runs:

- on ``workers`` local processes, each a :class:`~concurrent.futures.ProcessPoolExecutor` of
  one spawned process: a worker that dies (killed, out of memory) breaks its own executor
  only, so that the record it held, and no other, is not finished; a fresh worker takes its
  place and the batch goes on;
- on a Dask distributed cluster (``scheduler``, the address of its scheduler), whose workers
  have the package installed and read the inputs at the same paths (a shared file system).
  Dask gives the record of a worker that died to another; one that keeps killing its workers
  ends as not finished;
- or, with ``workers`` 0, in this process, one record after another (for a debugger).

A record whose JSON is in the summary folder is done and skipped; each record's JSON is
written when it ends, and the summary with it. Ctrl-C (KeyboardInterrupt) ends the workers and
leaves the summary of what finished.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from exo_has_sim.diagnosis.records import ERROR, Record, diagnose_record, record_id
from exo_has_sim.diagnosis.summary import UNFINISHED, SummaryFolder, SummaryRow, counts
from exo_has_sim.errors import DiagnosisError

#: Exit status: every record diagnosed, the model's structure describing each.
DESCRIBED_STATUS = 0
#: Exit status: a record could not be diagnosed (its error is in the summary); or, for one
#: record, the input cannot be read.
ERROR_STATUS = 1
#: Exit status: the model's structure does not describe a record's data (no error before).
STRUCTURE_STATUS = 3
#: Exit status: a record was not finished (its worker died): the same command does it.
UNFINISHED_STATUS = 4
#: Exit status: interrupted (Ctrl-C), as a shell reports SIGINT.
INTERRUPTED_STATUS = 128 + signal.SIGINT
#: The variables that make a worker compute on one thread, where the workers share the cores:
#: the integrator's (exo_has_sim.simulate.threads) and OpenBLAS's. With a process per core,
#: more threads only contend: pairs of draws diagnosed side by side ended 14-19 % sooner on one
#: thread each, for 15-18 % less CPU (2026-11-27, 2 cores), with the same JSON to the bit.
THREAD_VARIABLES = ('EXO_HAS_THREADS', 'OPENBLAS_NUM_THREADS')
#: ``PR_SET_PDEATHSIG`` from ``<linux/prctl.h>``.
PR_SET_PDEATHSIG = 1
#: Time to connect to a Dask scheduler [s].
CONNECT_TIMEOUT = 10.0

#: A record's result: its JSON document, or why it was not finished.
Ended = Callable[[Record, str, 'dict[str, Any] | str'], None]


@dataclass(frozen=True)
class BatchOutcome:
    """What a batch did: a row per record, in the records' order.

    Attributes
    ----------
    rows : list[SummaryRow]
        The records' rows, done before included.
    interrupted : bool
        Whether Ctrl-C ended the batch.
    summary : tuple[Path, Path]
        summary.md and summary.csv.

    """

    rows: list[SummaryRow]
    interrupted: bool
    summary: tuple[Path, Path]

    @property
    def status(self) -> int:
        """The batch's exit status, the first that applies.

        :data:`INTERRUPTED_STATUS` (Ctrl-C), :data:`UNFINISHED_STATUS` (a record not
        finished: run again), :data:`ERROR_STATUS` (a record could not be diagnosed),
        :data:`STRUCTURE_STATUS` (a record's verdict is the structure's), else
        :data:`DESCRIBED_STATUS`.
        """
        verdicts = {row.verdict for row in self.rows}
        for applies, status in ((self.interrupted, INTERRUPTED_STATUS),
                                (UNFINISHED in verdicts, UNFINISHED_STATUS),
                                (ERROR in verdicts, ERROR_STATUS),
                                ('structure' in verdicts, STRUCTURE_STATUS)):
            if applies:
                return status
        return DESCRIBED_STATUS


class ProgressBar:
    """A batch's progress on a stream: one line redrawn on a terminal, else a line per record.

    Parameters
    ----------
    stream : TextIO
        Where it is written (standard error by default).

    """

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.total = self.finished = 0
        self.started = time.monotonic()
        self.rows: list[SummaryRow] = []

    def start(self, total: int, before: int, where: str) -> None:
        """Say how many records there are, how many are done, where the rest are diagnosed."""
        self.total, self.started = total - before, time.monotonic()
        self._say(f'{total} record{"" if total == 1 else "s"}: {before} done before, '
                  + (f'{total - before} to diagnose {where}' if total > before
                     else 'none to diagnose'))

    def update(self, row: SummaryRow) -> None:
        """Show that a record ended."""
        self.finished += 1
        self.rows.append(row)
        if not self.tty:
            what = row.verdict + (f' {row.cause}' if row.cause else '')
            seconds = '' if row.seconds is None else f' ({row.seconds:.1f} s)'
            self._say(f'[{self.finished}/{self.total}] {row.record.name}: {what}{seconds}'
                      + (f': {row.error}' if row.error else ''))
            return
        elapsed = time.monotonic() - self.started
        left = elapsed / self.finished * (self.total - self.finished)
        width = 30
        done = round(width * self.finished / max(self.total, 1))
        self.stream.write(f'\r[{"#" * done}{"." * (width - done)}] {self.finished}/{self.total}'
                          f' {_clock(elapsed)} elapsed, {_clock(left)} left; '
                          f'{counts(self.rows).partition(": ")[2]}\033[K')
        self.stream.flush()

    def close(self) -> None:
        """End the redrawn line."""
        if self.tty and self.finished:
            self.stream.write('\n')
            self.stream.flush()

    def _say(self, line: str) -> None:
        print(line, file=self.stream, flush=True)


def _clock(seconds: float) -> str:
    minutes, second = divmod(round(seconds), 60)
    return f'{minutes // 60}:{minutes % 60:02d}:{second:02d}' if minutes >= 60 \
        else f'{minutes}:{second:02d}'


def run_batch(records: Sequence[Record], folder: Path, workers: int | None = None,
              scheduler: str | None = None, progress: ProgressBar | None = None) -> BatchOutcome:
    """Diagnose the records not yet done into a summary folder; return what the batch did.

    Parameters
    ----------
    records : Sequence[Record]
        The records, in the summary's order.
    folder : Path
        The summary folder (:class:`~exo_has_sim.diagnosis.summary.SummaryFolder`).
    workers : int or None
        Local worker processes (default: one per core this process may run on); 0: in this
        process. Ignored with ``scheduler``.
    scheduler : str or None
        The address of a Dask scheduler (``tcp://host:8786``) to run the records on.
    progress : ProgressBar or None
        Where the progress is shown (None: nowhere).

    Raises
    ------
    DiagnosisError
        If the records cannot be run at all (no worker process starts, no Dask scheduler at
        the address, dask not installed); the summary is written first.
    OSError
        If the summary folder cannot be made or written.

    """
    summary = SummaryFolder(folder)
    digests: dict[Path, str] = {}
    ids = list(dict.fromkeys((record_id(record, digests), record) for record in records))
    rows: dict[str, SummaryRow] = {}
    todo = []
    for id, record in ids:
        doc = summary.done(id)
        if doc is None:
            todo.append((record, id))
        else:
            rows[id] = SummaryRow.of(record, id, doc, done_before=True)

    def ordered() -> list[SummaryRow]:
        return [rows[id] for id, _ in ids if id in rows]

    def ended(record: Record, id: str, result: dict[str, Any] | str) -> None:
        if isinstance(result, str):
            rows[id] = SummaryRow.unfinished(record, id, result)
        else:
            summary.write(id, result)
            rows[id] = SummaryRow.of(record, id, result)
        summary.write_summary(ordered())
        if progress is not None:
            progress.update(rows[id])

    count = _cores() if workers is None else workers
    where = (f'on the Dask cluster at {scheduler}' if scheduler else 'in this process'
             if count == 0 else f'on {min(count, len(todo))} worker processes')
    if progress is not None:
        progress.start(len(ids), len(ids) - len(todo), where)
    interrupted, why = False, 'the batch ended before it'
    try:
        if not todo:
            pass
        elif scheduler:
            _on_dask(todo, scheduler, ended)
        elif count == 0:
            _in_process(todo, ended)
        else:
            _on_workers(todo, count, ended)
    except KeyboardInterrupt:
        interrupted, why = True, 'the batch was interrupted first'
    finally:
        if progress is not None:
            progress.close()
        for record, id in todo:
            rows.setdefault(id, SummaryRow.unfinished(record, id, why))
        paths = summary.write_summary(ordered(), interrupted)
    return BatchOutcome(ordered(), interrupted, paths)


def _cores() -> int:
    """Return the cores this process may run on (all of them where the system cannot say)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') \
        else os.cpu_count() or 1


def _failed(exc: BaseException) -> str:
    return f'the diagnosis failed: {type(exc).__name__}: {exc}'


def _in_process(todo: Sequence[tuple[Record, str]], ended: Ended) -> None:
    for record, id in todo:
        try:
            result: dict[str, Any] | str = diagnose_record(record)
        except Exception as exc:  # a fault of the diagnosis: the others go on
            result = _failed(exc)
        ended(record, id, result)


def _start_worker(parent: int) -> None:
    """Set a worker process up: Ctrl-C is the batch's to handle, and it ends with the batch."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith('linux'):
        # As exo_has_runtime.tether does (the ROS-free diagnosis does not import it): SIGTERM
        # when the batch's process dies, even by SIGKILL.
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(1)  # the batch ended before the request took effect


@contextlib.contextmanager
def single_threaded(on: bool = True) -> Iterator[None]:
    """Have the processes started within compute on one thread each (where ``on``).

    They take the variables at their start (OpenBLAS reads its own as numpy loads it); this
    process's environment is as it was on leaving.
    """
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    if on:
        os.environ.update(dict.fromkeys(THREAD_VARIABLES, '1'))
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


class _Worker:
    """A worker process: an executor of one, so that its death costs its own record only."""

    def __init__(self, one_thread: bool) -> None:
        # Spawned, not forked: the batch's process may hold threads (a test's rclpy).
        self.executor = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context('spawn'),
            initializer=_start_worker, initargs=(os.getpid(),))
        self.broken = False
        try:
            with single_threaded(one_thread):  # the process starts at the first task
                self.pid = self.executor.submit(os.getpid).result()
        except BrokenProcessPool as exc:
            self.executor.shutdown()
            msg = f'a worker process could not start: {exc}'
            raise DiagnosisError(msg) from exc

    def end(self) -> None:
        """End the process (SIGTERM), whatever it is doing."""
        if not self.broken:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGTERM)
            self.broken = True

    def close(self) -> None:
        """Shut the executor down: when its process has ended its record, or has ended."""
        self.executor.shutdown(wait=True, cancel_futures=True)


def _on_workers(todo: Sequence[tuple[Record, str]], count: int, ended: Ended) -> None:
    count = min(count, len(todo))
    queue = deque(todo)
    workers: list[_Worker] = []
    running: dict[Future[dict[str, Any]], tuple[int, Record, str]] = {}

    def feed(slot: int) -> None:
        if queue:
            record, id = queue.popleft()
            running[workers[slot].executor.submit(diagnose_record, record)] = (slot, record, id)

    try:
        for slot in range(count):
            workers.append(_Worker(count > 1))
            feed(slot)
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                slot, record, id = running.pop(future)
                try:
                    result: dict[str, Any] | str = future.result()
                except BrokenProcessPool:
                    worker = workers[slot]
                    worker.broken = True
                    result = (f'its worker process (pid {worker.pid}) ended while diagnosing '
                              'it (killed, or out of memory?)')
                    worker.close()
                    if queue:
                        workers[slot] = _Worker(count > 1)
                except Exception as exc:  # a fault of the diagnosis: the others go on
                    result = _failed(exc)
                ended(record, id, result)
                feed(slot)
    except BaseException:  # Ctrl-C, or a worker that could not start: end the others
        for worker in workers:  # all first: a second Ctrl-C may cut the closing short
            worker.end()
        for worker in workers:
            worker.close()
        raise
    for worker in workers:
        worker.close()


def _on_dask(todo: Sequence[tuple[Record, str]], address: str, ended: Ended) -> None:
    try:
        from dask.distributed import Client, KilledWorker, as_completed
    except ImportError as exc:
        msg = ("--scheduler needs Dask's distributed scheduler: pip install "
               f"'dask[distributed]' ({exc})")
        raise DiagnosisError(msg) from None
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        msg = f'cannot reach the Dask scheduler at {address}: {exc}'
        raise DiagnosisError(msg) from None
    with client:
        futures = {client.submit(diagnose_record, record, key=f'exo-has-diagnose-{id}',
                                 pure=False): (record, id) for record, id in todo}
        pending = set(futures)
        try:
            for future in as_completed(futures, loop=client.loop):
                pending.discard(future)
                record, id = futures[future]
                try:
                    result: dict[str, Any] | str = future.result()
                except KilledWorker as exc:
                    result = f'the Dask workers that took it died: {exc}'
                except Exception as exc:  # a fault of the diagnosis or a worker: go on
                    result = _failed(exc)
                ended(record, id, result)
        finally:
            if pending:
                client.cancel(list(pending))

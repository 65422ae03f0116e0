"""When a worker dies or a job runs too long: which jobs were running, and running them alone.

:class:`JobBoard` is memory shared by the launching process and its workers: per job, the
pid of the worker that started it (negative once the job ended) and when it started. When a
worker dies, the pool is broken and every job not yet done is lost with it; the board tells
the jobs that were running (to run again, each in a process of its own: :func:`each_alone`)
from those never started (to run on a new pool). :class:`Watchdog` stops the worker of a job
that runs longer than ``hydra.launcher.job_timeout_s``. When the sweep is stopped (Ctrl-C,
SIGTERM), the board says so and by which signal: the jobs already queued for the workers do
not start, and the running ones are interrupted (:meth:`JobBoard.running`,
:meth:`JobBoard.interrupt_running`), their records naming the signal.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from mpclab.core.signals import stoppable_job

log = logging.getLogger(__name__)


class WorkerDied(RuntimeError):
    """The worker process running a job died, also when it ran alone (its row's message)."""


class JobTimedOut(RuntimeError):
    """A job ran longer than ``hydra.launcher.job_timeout_s`` (its row's message)."""

    def __init__(self, timeout_s: float) -> None:
        super().__init__(f"it did not end within hydra.launcher.job_timeout_s={timeout_s:g} s "
                         "and its worker process was stopped")


@dataclass
class Lost:
    """A job whose process ended without its result: why, which process, how it ended."""

    error: WorkerDied | JobTimedOut
    pid: int | None
    how: str


class JobBoard:
    """Per job (its slot): the pid of the worker running it, negative once it ended, 0
    before it started; and when it started (``time.time()``); last, the signal that stopped
    the sweep (:meth:`stop`; 0 while it runs); in the shared array :attr:`cells`. A worker
    gets the array when it starts (a forked one inherits it) and wraps it again: the board
    itself is not pickled, since Hydra's plugin scan runs this module again and a pickled
    instance of the first run's class would not be found."""

    def __init__(self, cells: Any) -> None:
        self.cells = cells
        self.n_jobs = len(cells) // 2

    @classmethod
    def new(cls, ctx: Any, n_jobs: int) -> JobBoard:
        """A board of ``n_jobs`` jobs, none started, in shared memory of context ``ctx``."""
        return cls(ctx.RawArray("d", 2 * n_jobs + 1))

    @contextlib.contextmanager
    def running(self, slot: int) -> Iterator[None]:
        """Job ``slot`` runs in this worker within this block: noted on the board, and a
        stop signal interrupts it (:func:`~mpclab.core.signals.stoppable_job`: SIGINT, naming
        the signal the launcher passes on, SIGTERM and SIGHUP; a worker stopped by one of the
        last two ends after the block). A job that would start once the sweep has stopped
        does not: it raises ``KeyboardInterrupt`` at once (no row; the same command runs
        it)."""
        with stoppable_job(self.passed_on):
            try:
                self.start(slot)
                if self.stopped():  # after start: a stop is seen here or finds the job running
                    raise KeyboardInterrupt("the sweep stopped before this job started")
                yield
            finally:  # before the worker might end
                self.end(slot)

    def stop(self, by: signal.Signals = signal.SIGINT) -> None:
        """The sweep stops, by signal ``by``: its workers start no job after this."""
        self.cells[2 * self.n_jobs] = int(by)

    def stopped(self) -> bool:
        """Whether the sweep stopped (:meth:`stop`)."""
        return self.cells[2 * self.n_jobs] != 0

    def passed_on(self) -> str | None:
        """The name of the signal that stopped the sweep, where the launcher passes it on to
        its workers as SIGINT (:meth:`interrupt_running`); None for Ctrl-C (SIGINT itself)
        or while the sweep runs."""
        by = int(self.cells[2 * self.n_jobs])
        return None if by in (0, signal.SIGINT) else signal.Signals(by).name

    def start(self, slot: int) -> None:
        self.cells[2 * slot + 1] = time.time()
        self.cells[2 * slot] = os.getpid()

    def end(self, slot: int) -> None:
        self.cells[2 * slot] = -abs(self.cells[2 * slot])

    def started(self, slot: int) -> bool:
        return self.cells[2 * slot] != 0

    def interrupt_running(self) -> None:
        """Send SIGINT to the worker of every running job (it ends ``interrupted``, its
        steps so far recorded, naming the signal given to :meth:`stop`); call :meth:`stop`
        first."""
        for pid in {int(self.cells[2 * slot]) for slot in range(self.n_jobs)}:
            if pid > 0:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGINT)

    def overdue(self, timeout_s: float) -> list[tuple[int, int]]:
        """``(slot, pid)`` of every job running for longer than ``timeout_s``."""
        now, cells = time.time(), self.cells
        return [(slot, int(cells[2 * slot])) for slot in range(self.n_jobs)
                if cells[2 * slot] > 0 and now - cells[2 * slot + 1] > timeout_s]


class Watchdog:
    """A thread of the launching process that kills the worker of every job on ``board``
    that runs longer than ``timeout_s`` (its pool breaks; :attr:`stopped` names the jobs)."""

    def __init__(self, board: JobBoard, timeout_s: float) -> None:
        self.board, self.timeout_s = board, timeout_s
        self.stopped: set[int] = set()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="mpclab-job-timeout",
                                        daemon=True)

    def __enter__(self) -> Watchdog:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        self._thread.join()

    def _watch(self) -> None:
        while not self._done.wait(min(1.0, self.timeout_s / 10)):
            for slot, pid in self.board.overdue(self.timeout_s):
                if slot in self.stopped:
                    continue
                self.stopped.add(slot)
                log.error("a job ran longer than hydra.launcher.job_timeout_s=%g s: stopping "
                          "its worker (pid %d)", self.timeout_s, pid)
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:  # it ended meanwhile
                    pass


def kill_started_since(before: set[Any]) -> None:
    """Kill the child processes of this process started since ``before`` (what
    :func:`multiprocessing.active_children` was then), and wait for each to end."""
    procs = [p for p in multiprocessing.active_children() if p not in before]
    for proc in procs:
        proc.kill()
    for proc in procs:
        proc.join()


def death(exitcode: int) -> str:
    """How a process ended, from its exit code (negative: the signal that killed it)."""
    if exitcode >= 0:
        return f"exit code {exitcode}"
    try:
        return f"killed by {signal.Signals(-exitcode).name}"
    except ValueError:
        return f"killed by signal {-exitcode}"


def _alone(send: Connection, initializer: Callable[..., None], initargs: tuple[Any, ...],
           run: Callable[..., Any], idx: int, overrides: Sequence[str], slot: int) -> None:
    """Set up this new process as a worker, run one job and send back its result."""
    initializer(*initargs)
    send.send(run(idx, overrides, slot))
    send.close()


def each_alone(
    ctx: Any, run: Callable[..., Any], initializer: Callable[..., None],
    initargs: tuple[Any, ...], jobs: Sequence[tuple[int, Sequence[str]]], slots: list[int],
    n: int, timeout_s: float | None,
) -> dict[int, Any]:
    """Run ``run(idx, overrides, slot)`` for the jobs at ``slots``, each in a new process of
    its own (``n`` at a time); per slot its result, or :class:`Lost` where its process
    died or ran out of time."""
    pending, out = list(slots), {}
    running: dict[Connection, tuple[int, Any, float]] = {}
    while pending or running:
        while pending and len(running) < n:
            slot = pending.pop(0)
            receive, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_alone, daemon=True,
                               args=(send, initializer, initargs, run, *jobs[slot], slot))
            proc.start()
            send.close()  # the child holds the only writing end: its death is an EOF
            deadline = time.time() + timeout_s if timeout_s else float("inf")
            running[receive] = (slot, proc, deadline)
        next_deadline = min(d for _, _, d in running.values())
        ready = wait(list(running), timeout=max(0.0, next_deadline - time.time())
                     if next_deadline < float("inf") else None)
        if not ready:  # a job ran out of time: stop its process; it reads as EOF next
            for _, proc, deadline in running.values():
                if deadline <= time.time():
                    proc.kill()
            continue
        for receive in ready:
            slot, proc, deadline = running.pop(receive)
            try:
                result: Any = receive.recv()
            except EOFError:  # it died without sending
                result = None
            receive.close()
            proc.join()
            if result is None:
                how = death(proc.exitcode or 0)
                error = (JobTimedOut(timeout_s) if timeout_s and deadline <= time.time()
                         else WorkerDied(f"the worker process running this job died ({how}), "
                                         "also when it ran alone: out of memory, or a crash in "
                                         "native code?"))
                result = Lost(error, proc.pid, how)
            out[slot] = result
    return out

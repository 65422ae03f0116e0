"""SIGTERM and SIGHUP stop a run as Ctrl-C does: the steps so far are recorded.

SLURM, ``timeout``, a container stop and Ray's cancel send SIGTERM; a closed terminal sends
SIGHUP. Within :func:`signals_interrupt`, either raises :class:`Terminated` (a
``KeyboardInterrupt``) in the main thread, so that a run ends ``interrupted`` with its
partial record and a sweep's launcher stops its workers the same way. A second signal ends
the process at once (the system's handling), unless it comes within :data:`SAME_STOP_S` of
the first: ``timeout`` sends its signal to its command and again to the command's process
group, and ``uv run`` passes on a signal that its process group got too.

A sweep's worker process takes the stop within a job (:func:`stoppable_job`), whether it
comes from the launcher or is sent to the whole process group (as SLURM and ``timeout``
do): its job ends ``interrupted`` with its record, and a worker stopped by SIGTERM or SIGHUP
then ends. While the launcher waits for its workers, a second signal ends them and it at once
(:func:`call_first_on_stop`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

#: the signals that stop a run as an interrupt does
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
#: the signals that stop a job of a sweep's worker
JOB_STOP_SIGNALS = (signal.SIGINT, *STOP_SIGNALS)
#: a stop signal within this many seconds of the first is the same stop sent again, not a
#: second one
SAME_STOP_S = 1.0
#: when this process got its first stop signal (``time.monotonic()``), if it did
_STOPPED_AT: list[float] = []


class Terminated(KeyboardInterrupt):
    """A run or sweep stopped by a signal other than Ctrl-C's (its name is the message)."""


#: the stop signal received within :func:`signals_interrupt`, if any: native code (a solver)
#: may hand the :class:`Terminated` back as an error of its own
_RECEIVED: list[str] = []


def received() -> Terminated | None:
    """The :class:`Terminated` of a stop signal this process received, or None."""
    return Terminated(_RECEIVED[-1]) if _RECEIVED else None


def stopped_by(exc: BaseException) -> str:
    """What stopped a run: the signal's name for a :class:`Terminated`, else ``Ctrl-C``."""
    return str(exc.args[0]) if isinstance(exc, Terminated) and exc.args else "Ctrl-C"


def signal_of(exc: BaseException) -> signal.Signals:
    """The signal behind an interrupt: SIGTERM or SIGHUP for a :class:`Terminated` that
    names it, else SIGINT (Ctrl-C, or no signal)."""
    name = stopped_by(exc)
    return signal.Signals[name] if name in signal.Signals.__members__ else signal.SIGINT


def interrupted(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt behind ``exc``, if it is one that native code handed back as another
    error (it must stop the run, not count as a failed solve); None otherwise. CasADi's
    solvers check for SIGINT between iterations and raise ``RuntimeError('KeyboardInterrupt')``
    (their ``KeyboardInterruptException``); a SIGINT inside a generated function comes back
    as ``SystemError: ... returned a result with an exception set``, raised from the
    ``KeyboardInterrupt``; a SIGTERM or SIGHUP received meanwhile (:func:`received`) makes
    any error an interrupt."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return cause
        if isinstance(cause, RuntimeError) and str(cause).strip().endswith("KeyboardInterrupt"):
            return received() or KeyboardInterrupt()
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return received()


def _stop(signum: int, frame: FrameType | None) -> None:
    _STOPPED_AT[:] = [time.monotonic()]
    for sig in STOP_SIGNALS:
        signal.signal(sig, _stop_again)
    _RECEIVED.append(signal.Signals(signum).name)
    raise Terminated(_RECEIVED[-1])


def _stop_again(signum: int, frame: FrameType | None) -> None:
    """A stop signal after the first: the same stop sent again (ignored), or a second one
    (the system's handling: the process ends)."""
    if not _same_stop():
        default_stop_signals()
        signal.raise_signal(signum)


def _same_stop() -> bool:
    """Whether a stop signal now is the first one sent again (:data:`SAME_STOP_S`)."""
    return bool(_STOPPED_AT) and time.monotonic() - _STOPPED_AT[-1] < SAME_STOP_S


def default_stop_signals() -> None:
    """The system's handling of SIGTERM and SIGHUP (the process ends)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


def worker_signals() -> None:
    """The signal handling of a sweep's worker process between its jobs, whatever it
    inherited: SIGTERM and SIGHUP end it as they end any process (the pool stops a worker
    with SIGTERM); SIGINT is ignored. Within a job, :func:`stoppable_job`."""
    default_stop_signals()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def stoppable_job(passed_on: Callable[[], str | None] = lambda: None) -> Iterator[None]:
    """A job of a sweep's worker process runs within this block: the first of SIGINT,
    SIGTERM and SIGHUP raises an interrupt (the job ends ``interrupted`` with its record):
    :class:`Terminated` naming SIGTERM or SIGHUP; for SIGINT, naming ``passed_on()``, the
    signal that the launcher passes on to its workers as SIGINT, or ``KeyboardInterrupt``
    (Ctrl-C) if None. Set explicitly, whatever the process inherited: a process started
    with SIGINT ignored (a background job ``cmd &`` of a shell script) keeps ignoring it.

    The signals after the first are noted, not raised: the job's record is written whole,
    also when a signal sent to the whole process group reaches the worker twice (from its
    sender, and passed on by the launcher). A worker that received SIGTERM or SIGHUP ends
    when the block ends, killed by that signal, its record written: the pool stops a worker
    with SIGTERM (when another one died) and waits for it, and a stop sent to the group ends
    the sweep. Outside the block, the handling is :func:`worker_signals`'."""
    received: list[int] = []
    raising = True  # until the first signal, and while the job runs

    def stop(signum: int, frame: FrameType | None) -> None:
        nonlocal raising
        received.append(signum)
        if not raising:
            return
        raising = False
        name = passed_on() if signum == signal.SIGINT else signal.Signals(signum).name
        if name is None:
            raise KeyboardInterrupt
        _RECEIVED.append(name)  # native code may hand the interrupt back as another error
        raise Terminated(name)

    saved = {sig: signal.signal(sig, stop) for sig in JOB_STOP_SIGNALS}
    _RECEIVED.clear()
    try:
        yield
    finally:
        raising = False  # the job is over: a signal from now on is noted
        _RECEIVED.clear()
        for sig, handler in saved.items():  # a signal pending now is handled first
            signal.signal(sig, handler)
        ending = [sig for sig in received if sig in STOP_SIGNALS]
        if ending:
            _end_by(ending[0])


def _end_by(signum: int) -> None:
    """End this process as ``signum`` does by default (its output flushed first)."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    signal.signal(signum, signal.SIG_DFL)
    signal.raise_signal(signum)
    os._exit(128 + signum)  # pragma: no cover  (the signal ended the process)


@contextlib.contextmanager
def call_first_on_stop(first: Callable[[], Any]) -> Iterator[None]:
    """Within this block, entered at a stop, SIGINT, SIGTERM and SIGHUP (those not ignored)
    call ``first()``, then do what they did before the block: raise (a Python handler), or
    end the process (the system's handling); unless they are that stop sent again (within
    :data:`SAME_STOP_S` of it, ignored). A launcher waiting for its workers to record their
    stopped jobs ends them this way, at a second signal, before it ends."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread handles signals
        return
    if not _same_stop():  # the stop was Ctrl-C (Python's own handler): from now on
        _STOPPED_AT[:] = [time.monotonic()]
    saved = {sig: signal.getsignal(sig) for sig in JOB_STOP_SIGNALS}
    saved = {sig: handler for sig, handler in saved.items() if handler != signal.SIG_IGN}

    def restore() -> None:
        for sig, handler in saved.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)

    def call(signum: int, frame: FrameType | None) -> None:
        if _same_stop():
            return
        restore()  # a further signal: as before the block
        first()
        handler = saved[signal.Signals(signum)]
        if callable(handler):
            handler(signum, frame)
        else:
            signal.raise_signal(signum)

    for sig in saved:
        signal.signal(sig, call)
    try:
        yield
    finally:
        restore()


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within this block, SIGTERM and SIGHUP raise :class:`Terminated` (main thread only;
    elsewhere the block changes nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS}
    _RECEIVED.clear()
    _STOPPED_AT.clear()
    try:
        yield
    finally:
        _RECEIVED.clear()
        for sig, handler in saved.items():
            signal.signal(sig, handler)

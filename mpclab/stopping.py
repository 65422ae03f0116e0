"""SIGTERM and SIGHUP stop a run as Ctrl-C does: the steps so far are recorded.

SLURM, ``timeout``, a container stop and Ray's cancel send SIGTERM; a closed terminal sends
SIGHUP. Within :func:`signals_interrupt`, either raises :class:`Terminated` (a
``KeyboardInterrupt``) in the main thread, so that a run ends ``interrupted`` with its
partial record and a sweep's launcher stops its workers the same way. The handlers go back
to the system's at the first signal: a second one ends the process at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

#: the signals that stop a run as an interrupt does
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """A run or sweep stopped by a signal other than Ctrl-C's (its name is the message)."""


#: the stop signal received within :func:`signals_interrupt`, if any: native code (a solver)
#: may hand the :class:`Terminated` back as an error of its own
_RECEIVED: list[str] = []


def received() -> Terminated | None:
    """The :class:`Terminated` of a stop signal this process received, or None."""
    return Terminated(_RECEIVED[-1]) if _RECEIVED else None


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
    default_stop_signals()  # a second signal: the system's handling, the process ends
    _RECEIVED.append(signal.Signals(signum).name)
    raise Terminated(_RECEIVED[-1])


def default_stop_signals() -> None:
    """The system's handling of SIGTERM and SIGHUP (the process ends)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


def worker_signals() -> None:
    """The signal handling of a sweep's worker process, whatever it inherited: SIGTERM and
    SIGHUP end it as they end any process (the pool stops a worker with SIGTERM); SIGINT is
    ignored, except within :func:`interruptible` (around each job it runs)."""
    default_stop_signals()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Within this block SIGINT raises ``KeyboardInterrupt``, whatever it did before (then
    restored). Set explicitly because a process started with SIGINT ignored (a background job
    ``cmd &`` of a shell script) keeps ignoring it: a sweep's launcher passes a stop on to the
    workers running a job as SIGINT, and such a job would run on to its end."""
    saved = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within this block, SIGTERM and SIGHUP raise :class:`Terminated` (main thread only;
    elsewhere the block changes nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS}
    _RECEIVED.clear()
    try:
        yield
    finally:
        _RECEIVED.clear()
        for sig, handler in saved.items():
            signal.signal(sig, handler)

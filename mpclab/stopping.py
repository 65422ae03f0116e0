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


def _stop(signum: int, frame: FrameType | None) -> None:
    for sig in STOP_SIGNALS:  # a second signal: the system's handling, the process ends
        signal.signal(sig, signal.SIG_DFL)
    raise Terminated(signal.Signals(signum).name)


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within this block, SIGTERM and SIGHUP raise :class:`Terminated` (main thread only;
    elsewhere the block changes nothing)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)

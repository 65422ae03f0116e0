"""Silence what compiled libraries print straight to the process's standard output."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def c_stdout_silenced() -> Iterator[None]:
    """Send file descriptor 1 to /dev/null for the duration (C ``printf`` included).

    qpOASES prints its licence banner from C every time a solver is built, whatever its
    ``printLevel``; Python's ``sys.stdout`` cannot catch that, the descriptor can.
    """
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output at all: nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        sys.stdout.flush()
        _flush_c_stdio()  # C stdio buffers what it printed when stdout is not a terminal
        os.dup2(saved, 1)
        os.close(saved)


def _flush_c_stdio() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask (not on this platform)
        pass

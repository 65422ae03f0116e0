"""The pool launcher's recovery parts alone: the job board (also when the sweep stops), the
time-limit watchdog, and jobs run each in a process of their own
(``hydra_plugins/mpclab_launcher/recovery.py``)."""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import time

import pytest

from hydra_plugins.mpclab_launcher import pool_launcher, recovery
from hydra_plugins.mpclab_launcher.pool_launcher import PoolLauncher, StartMethod
from mpclab.core.errors import ConfigError
from mpclab.core.signals import SAME_STOP_S, call_first_on_stop, worker_signals

CTX = multiprocessing.get_context("fork")


def _setup() -> None:
    pass


def _job(idx: int, overrides: list[str], slot: int) -> tuple[int, str]:
    if "hang" in overrides:  # returns, with a result, unless it is stopped at its limit
        time.sleep(30)
    if "die" in overrides:
        os.kill(os.getpid(), signal.SIGKILL)
    return idx, os.getpid()


def _wait_started(board: recovery.JobBoard, slot: int) -> None:
    deadline = time.time() + 60
    while not board.started(slot) and time.time() < deadline:
        time.sleep(0.01)


def test_each_alone_returns_results_and_says_how_a_job_was_lost() -> None:
    jobs = [(10, ["ok"]), (11, ["die"]), (12, ["hang"]), (13, ["ok"])]
    out = recovery.each_alone(CTX, _job, _setup, (), jobs, [0, 1, 2, 3], n=2, timeout_s=2.0)
    assert out[0][0] == 10 and out[3][0] == 13
    assert out[0][1] != out[3][1] != os.getpid()  # each in a process of its own
    died, hung = out[1], out[2]
    assert isinstance(died, recovery.Lost) and isinstance(died.error, recovery.WorkerDied)
    assert died.how == "killed by SIGKILL" and "SIGKILL" in str(died.error)
    assert isinstance(hung, recovery.Lost) and isinstance(hung.error, recovery.JobTimedOut)
    assert "job_timeout_s=2 s" in str(hung.error)


def test_the_watchdog_stops_only_the_overdue_job() -> None:
    board = recovery.JobBoard.new(CTX, 3)

    def worker(slot: int, seconds: float) -> None:
        board.start(slot)
        time.sleep(seconds)
        board.end(slot)

    procs = [CTX.Process(target=worker, args=(slot, s)) for slot, s in
             enumerate([600.0, 0.2, 600.0])]
    with recovery.Watchdog(board, timeout_s=1.5) as dog:
        for p in procs:
            p.start()
        procs[1].join()
        _wait_started(board, 2)  # its own start comes first
        board.end(2)  # slot 2 counts as ended: its process is not this watchdog's to stop
        procs[0].join(timeout=60)
    assert procs[0].exitcode == -signal.SIGKILL and procs[1].exitcode == 0
    assert dog.stopped == {0} and board.started(1)
    # a stopped job stays on the board as running (its worker could not say it ended); the
    # pool's breakage tells the rest
    assert board.overdue(1.5) == [(0, procs[0].pid)]
    assert procs[2].is_alive()
    procs[2].kill()
    procs[2].join()


def test_a_stopped_sweep_interrupts_the_running_job_and_starts_no_other() -> None:
    """A worker ignores SIGINT between jobs (as it would inherit it from a process started as
    a script's background job) and takes it as an interrupt within one."""
    board = recovery.JobBoard.new(CTX, 2)
    receive, send = CTX.Pipe(duplex=False)

    def worker() -> None:
        worker_signals()
        os.kill(os.getpid(), signal.SIGINT)  # between jobs: ignored
        for slot, seconds in ((0, 600.0), (1, 0.0)):
            try:
                with board.running(slot):
                    time.sleep(seconds)
                send.send((slot, "ran"))
            except KeyboardInterrupt as exc:
                send.send((slot, f"interrupted {exc}".strip()))

    proc = CTX.Process(target=worker)
    proc.start()
    _wait_started(board, 0)
    board.stop(signal.SIGTERM)  # the launcher's own stop, passed on as SIGINT
    board.interrupt_running()
    assert receive.poll(60)
    assert [receive.recv(), receive.recv()] == [
        (0, "interrupted SIGTERM"), (1, "interrupted the sweep stopped before this job started")]
    proc.join(timeout=60)
    assert proc.exitcode == 0 and board.stopped()  # stopped by the launcher: it goes on
    assert not board.overdue(0.0)  # no job is left running


def test_a_worker_given_sigterm_in_a_job_records_it_then_ends() -> None:
    """SIGTERM sent to the worker itself (to the sweep's process group, or by the pool): the
    job is interrupted once, also when the launcher's SIGINT follows, and its end (the
    record) comes before the worker ends, killed by SIGTERM."""
    board = recovery.JobBoard.new(CTX, 1)
    receive, send = CTX.Pipe(duplex=False)

    def job() -> None:
        worker_signals()
        with board.running(0):
            try:
                while True:  # at work
                    time.sleep(0.01)
            except KeyboardInterrupt as exc:  # writing its record, the launcher's SIGINT
                os.kill(os.getpid(), signal.SIGINT)  # comes: noted, not raised
                time.sleep(0.1)
                send.send(repr(exc))
        send.send("not reached")

    proc = CTX.Process(target=job)
    proc.start()
    _wait_started(board, 0)
    os.kill(proc.pid, signal.SIGTERM)
    proc.join(timeout=60)
    assert proc.exitcode == -signal.SIGTERM
    assert receive.recv() == "Terminated('SIGTERM')"
    assert not receive.poll(0)


def test_a_second_signal_calls_first_then_does_what_it_did() -> None:
    """The stop sent again at once (``timeout`` sends it to its command and to the command's
    process group) is not a second one."""
    receive, send = CTX.Pipe(duplex=False)

    def launcher() -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        with call_first_on_stop(lambda: send.send("first")):
            os.kill(os.getpid(), signal.SIGTERM)
            send.send("again")
            time.sleep(SAME_STOP_S)
            os.kill(os.getpid(), signal.SIGTERM)
            send.send("not reached")

    proc = CTX.Process(target=launcher)
    proc.start()
    proc.join(timeout=60)
    assert proc.exitcode == -signal.SIGTERM
    assert [receive.recv(), receive.recv()] == ["again", "first"]
    assert not receive.poll(0)


def test_a_bad_time_limit_is_one_message_naming_it() -> None:
    for bad in (-1, 0, "abc", float("nan")):
        with pytest.raises(ConfigError, match=r"job_timeout_s: expected seconds > 0, or null"):
            PoolLauncher(job_timeout_s=bad)
    assert PoolLauncher(job_timeout_s="2.5").timeout_s == pytest.approx(2.5)
    assert PoolLauncher().timeout_s is None


def test_the_constructor_checks_counts_and_choices() -> None:
    """What the launcher's schema cannot say (ranges; a launcher built in Python has no
    schema): one ConfigError naming the key, the value and what is valid."""
    for bad in (0, -2, 1.5, True, "two", None):
        with pytest.raises(ConfigError, match=r"^hydra\.launcher\.n_jobs: expected a whole "
                                              r"number >= 1, or -1 \(one worker per core\)"):
            PoolLauncher(n_jobs=bad)
    with pytest.raises(ConfigError, match=r"threads_per_worker: expected a whole number >= 1"):
        PoolLauncher(threads_per_worker=0)
    with pytest.raises(ConfigError, match=r"start_method: unknown choice 'thread'; valid: "
                                          r"fork, forkserver, spawn"):
        PoolLauncher(start_method="thread")
    launcher = PoolLauncher(n_jobs="2", threads_per_worker=2.0, start_method=StartMethod.spawn)
    assert (launcher.n_jobs, launcher.threads, launcher.start_method) == (2, 2, "spawn")
    assert PoolLauncher(n_jobs=-1).n_jobs == -1


def test_more_workers_than_cores_is_a_warning(monkeypatch, caplog) -> None:
    monkeypatch.setattr(pool_launcher, "usable_cores", lambda: 2)
    with caplog.at_level(logging.WARNING):
        assert PoolLauncher(n_jobs=-1).workers(10) == 2
        assert PoolLauncher(n_jobs=2).workers(10) == 2
        assert PoolLauncher(n_jobs=5).workers(3) == 3  # no more workers than jobs
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == ["3 workers on 2 core(s): jobs share cores, so their compute times are "
                        "inflated (the tables mark such runs 'contended'); "
                        "hydra.launcher.n_jobs=-1 runs one worker per core"]

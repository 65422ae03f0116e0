"""Sweeps: fault rows and resume for multirun jobs, progress and aggregation callbacks.

A Hydra multirun (``python -m mpclab -m ...``) runs each job through :func:`jobs.run_job`,
which skips a job whose run record is already complete (resume) and turns an exception into
an ``error`` row instead of aborting the sweep. :class:`callbacks.SweepCallback` shows
progress and, at the end, aggregates every job's ``summary.json`` with :mod:`mpclab.tables`.
"""

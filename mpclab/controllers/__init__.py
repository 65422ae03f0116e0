"""Solver backends: one file per backend, each a :class:`~mpclab.controllers.base.Controller`."""

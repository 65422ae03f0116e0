"""Constraints of an MPC problem, declared beside the objective terms (``objective.constraints``)."""

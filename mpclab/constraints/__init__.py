"""Constraints of an MPC problem, declared beside its objective terms (objective.constraints)."""

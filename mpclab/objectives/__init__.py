"""Objective terms (J1..J5, quadratic tracking, effort) and their composition."""

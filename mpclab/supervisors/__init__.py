"""Objective-set switching (e.g. BUG2)."""

"""The dynamic window approach (Fox, Burgard, Thrun 1997): a sampling local planner, the
navigation benchmarks' classic peer."""

"""The world a run happens in: scenarios (start, goal, stop rules), obstacles, sensors."""

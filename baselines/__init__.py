"""Baseline policies (STP tracking, avoidance and switching controllers, safety filter, scripted
intruders) arrive with the environment; see the open issues."""

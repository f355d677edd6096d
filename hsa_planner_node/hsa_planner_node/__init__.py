"""Planner node: steady-state setpoint planning service and a setpoint sequencer for step and
contour trajectories."""

"""The setpoint sequencer's timing: its supervision period and when it requests point 0 (no JAX, no
ROS).

One definition for the node (``hsa_planner_node.setpoint_sequencer``, which runs the supervision
timer) and for the ROS-free experiments (``hsa_core.sim.experiment``, ``hsa_core.sim.closed_loop``,
which reproduce its first request), so that the graph in lockstep and the experiments in one process
request point 0 at the same instant.
"""

from __future__ import annotations

SUPERVISION_PERIOD_NS = 50_000_000
"""[ns] period of the sequencer's supervision timer: service discovery, start delay, plan timeouts,
finish hold."""


def first_point_ns(start_delay: float) -> int:
    """When the sequencer requests point 0 [ns]: at its first supervision tick (50 ms) it finds the
    planner and waits ``start_delay`` [s]; the request goes out at the first later supervision tick
    at or after that."""
    start_at = SUPERVISION_PERIOD_NS + int(round(start_delay * 1e9))
    ticks = max(2, -(-start_at // SUPERVISION_PERIOD_NS))
    return ticks * SUPERVISION_PERIOD_NS

"""The newest phi_cmd on its way to the servos: clipped to [0, φ_max], clamped to the absolute goal
limits and rate-limited on the node clock (planning_and_control.md §7). ROS-free: the node
writes and publishes."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from hsa_core.model.actuation import GoalRateLimiter, MotorLimits, MotorMap


@dataclasses.dataclass(frozen=True)
class GoalStep:
    """A goal to write [ticks]; rate_limited: the limit shortened a new command's goal; clipped: why
    the command was clipped or clamped (for the counters and the throttled log), or None."""

    ticks: np.ndarray
    rate_limited: bool
    clipped: str | None


@dataclasses.dataclass
class GoalPipeline:
    """Newest command, its clamped target and the goal in force (times: node-clock seconds)."""

    command: Any = None  # the newest accepted PlanarActuation (phi, source_stamp, header.stamp)
    target: np.ndarray | None = None  # its clamped goal ticks
    target_source: Any = None  # the source_stamp of the target's command
    pending: bool = False  # the command has not been turned into a target yet
    limiter: GoalRateLimiter = dataclasses.field(default_factory=GoalRateLimiter)

    def take(self, command: Any) -> None:
        """A new accepted command: the next write turns it into the target."""
        self.command, self.pending = command, True

    def clear(self) -> None:
        """Discard the command and the target (torque-on, E-stop, reboot, activation)."""
        self.command = self.target = None
        self.pending = False

    def drop_target(self) -> None:
        """Stale command (watchdog) or torque off: nothing more is written, the last goal stays."""
        self.target, self.pending = None, False

    def next_goal(
        self, now: float, motor_map: MotorMap, limits: MotorLimits, max_rate: float, period: float
    ) -> GoalStep | None:
        """The goal to write at ``now`` [s]: a new command's (clipped to the map's [0, phi_max]), or
        the next step of a rate-limited ramp; None when there is nothing new to write. ``max_rate``
        [rad/s] (0 = no limit), ``period`` [s] of the control cycle."""
        fresh, clipped, phi_max = self.pending, None, motor_map.phi_max
        if fresh:
            phi = np.asarray(self.command.phi)
            within = np.clip(phi, 0.0, phi_max)
            self.target, clamped = limits.clamp(motor_map.goal_ticks(within))
            if np.any(within != phi):
                clipped = f"phi {np.round(phi, 4).tolist()} rad outside [0, {phi_max:.4f}]"
            elif np.any(clamped):
                clipped = f"goal ticks clamped to the limits for phi {phi}"
            self.target_source, self.pending = self.command.source_stamp, False
        if self.target is None:
            return None
        goal = self.limiter.limited(
            self.target, now, max_rate, period, lambda g: limits.clamp(g)[0]
        )
        if not fresh and np.array_equal(goal, self.limiter.goal):
            return None
        return GoalStep(goal, fresh and not np.array_equal(goal, self.target), clipped)

    def written(self, goal: np.ndarray, now: float) -> None:
        """The goal was written at ``now``."""
        self.limiter.written(goal, now)

"""ROS-free decisions of the dynamixel_driver: the goal-rate limiter on the node clock and the reboot admission.

Time is passed in explicitly (seconds of the node clock: wall time, or simulated time with ``use_sim_time``), so the
same inputs give the same decisions whatever the machine's load.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hsa_core.actuation import limit_goal_rate


@dataclass
class GoalRateLimiter:
    """Goal-rate limit that is order-independent within one clock instant.

    A write at time ``now`` may move the goal at most ``max_rate · min(now − t_a, period)`` from the goal in force at
    ``t_a``, the last EARLIER instant at which a goal was written. Several writes at the same instant (the cycle
    timer and a ``phi_cmd`` arriving in the same simulated instant, in either order) are all measured from that same
    goal, so the last target of the instant alone decides the final goal. On the wall clock every write has its own
    instant and this is the plain "time since the last write" limit.
    """

    _anchor_time: float = 0.0  # t_a: the last instant before the current one at which a goal was written
    _anchor_goal: np.ndarray | None = None  # the goal in force at the end of t_a
    _time: float = 0.0  # the instant of the latest write
    _goal: np.ndarray | None = None  # the latest goal written

    def reset(self, goal: ArrayLike) -> None:
        """Torque came on holding ``goal``: it counts as in force since long ago, so the first write may move it by a
        full period's step (the held goal needs no ramp-in)."""
        held = np.asarray(goal, dtype=np.int64)
        self._anchor_time, self._anchor_goal, self._time, self._goal = -math.inf, held, -math.inf, held

    @property
    def goal(self) -> np.ndarray | None:
        """The latest goal written (or held since ``reset``), None before the first reset."""
        return self._goal

    def limited(self, target: ArrayLike, now: float, max_rate: float, period: float,
                clamp: Callable[[np.ndarray], np.ndarray] = lambda g: g) -> np.ndarray:
        """The goal a write of ``target`` at ``now`` may set ([ticks]); ``max_rate`` [rad/s] 0 = no limit.

        ``clamp`` maps the rate-limited goal back into the absolute goal limits.
        """
        if self._goal is None:
            raise RuntimeError("GoalRateLimiter.limited before reset: no goal in force")
        target = np.asarray(target, dtype=np.int64)
        if max_rate <= 0.0:
            return target
        base_time, base_goal = (self._anchor_time, self._anchor_goal) if now == self._time else (self._time,
                                                                                                 self._goal)
        dt = min(max(now - base_time, 0.0), period)  # a clock that jumped back allows no motion at that instant
        return np.asarray(clamp(limit_goal_rate(base_goal, target, dt, max_rate)), dtype=np.int64)

    def written(self, goal: ArrayLike, now: float) -> None:
        """Record that ``goal`` was written at ``now`` (a new instant makes the previous one the anchor)."""
        if now != self._time:
            self._anchor_time, self._anchor_goal = self._time, self._goal
        self._time, self._goal = now, np.asarray(goal, dtype=np.int64)


def reboot_refusal(active: bool, link_up: bool, torque_on: bool, tracking: bool) -> str | None:
    """Why a servo reboot must be refused now, or None.

    A reboot drops the servo's torque at once (the instruction resets its RAM), so it is refused while the robot is
    tracking fresh commands with torque on; holding or idle servos may be rebooted (the driver switches every servo's
    torque off first, so a rod pair is never left half held).
    """
    if not active:
        return "node is not active"
    if not link_up:
        return "bus not connected"
    if torque_on and tracking:
        return ("torque is on and the robot is tracking fresh phi_cmd: stop the commands (or call set_torque(false)) "
                "before a reboot")
    return None

"""Check chain of the mocap bridge as a pure state machine: one platform sample in, accept (χ_ee) or reject (reason).

Times are integer nanoseconds on one clock: ``now_ns`` is the bridge's clock when the sample arrived, ``stamp_ns`` the
sample's header stamp, which the mocap driver (or the simulator) sets on that same clock. Checks, in this order; the
first that fails rejects the sample and leaves the state unchanged:

``frame``        header frame_id differs from the expected one (an empty or ``map`` frame is never relabelled)
``non_finite``   a NaN or inf in the position or quaternion
``quaternion``   |‖q‖ − 1| > quaternion_tolerance
``stale``        now − stamp > max_age (max_age > 0)
``future``       stamp − now > max_future: a stamp the clock has not reached cannot be a measurement
``duplicate``    stamp equal to the newest accepted stamp
``out_of_order`` stamp older than the newest accepted stamp
``no_base``      the frame chain needs a measured base pose and none was accepted yet
``workspace``    χ_ee outside the plausibility box
``jump``         χ_ee moved faster than max_speed / max_angular_speed since the newest accepted sample

Only an accepted sample advances the ordering reference. Because a sample stamped more than max_future ahead is
rejected, one bad stamp can hold back genuine samples for at most max_future (two 200 Hz periods by default). A
reference further ahead of the clock than max_future can only come from a clock that went back (a restarted
simulation or bag); it is then dropped, so the bridge follows the new time line from its first sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hsa_core import mocap

REASONS = ("frame", "non_finite", "quaternion", "stale", "future", "duplicate", "out_of_order", "no_base", "workspace",
           "jump")
"""Rejection reasons in check order."""

MAX_FUTURE = 0.01
"""[s] default bound on how far a stamp may lie ahead of the clock: two periods at 200 Hz."""


@dataclass(frozen=True)
class GateConfig:
    """Bounds of the check chain (SI units; an infinite speed or a max_age of 0 disables that check)."""

    frame_id: str = "world"
    quaternion_tolerance: float = 0.01
    max_age: float = 0.5  # [s]
    max_future: float = MAX_FUTURE  # [s]
    max_speed: float = 4.0  # [m/s]
    max_angular_speed: float = 40.0  # [rad/s]
    workspace: mocap.WorkspaceBox = field(default_factory=mocap.WorkspaceBox)


class Sample(NamedTuple):
    """One measured body pose: stamp [ns], frame_id, world position [m] and quaternion (x, y, z, w)."""

    stamp_ns: int
    frame_id: str
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


class Verdict(NamedTuple):
    """Outcome of one check: reason is None and chiee set when accepted, else the reason and a text."""

    reason: str | None
    text: str
    chiee: np.ndarray | None = None


class MocapGate:
    """Accepts or rejects platform samples; keeps the newest accepted stamp and pose and the newest valid base pose."""

    def __init__(self, config: GateConfig, chain: mocap.MocapConfig = mocap.DEFAULT_CONFIG,
                 base_position: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Checks with ``config``; frame chain ``chain``, base at ``base_position`` unless the chain measures it."""
        self.config = config
        self.chain = chain
        self.base_position = base_position
        self.base: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # newest valid measured base pose
        self.last_stamp_ns: int | None = None
        self.last_chiee: np.ndarray | None = None
        self.time_resets = 0

    def base_sample(self, sample: Sample) -> str | None:
        """Keep a measured base pose; return why it is unusable (wrong frame, non-finite, quaternion), or None."""
        problem = self._frame_problem(sample) or mocap.pose_problem(
            sample.position, sample.quaternion, self.config.quaternion_tolerance)
        if problem is None:
            self.base = tuple(sample.position), tuple(sample.quaternion)
        return problem

    def check(self, sample: Sample, now_ns: int) -> Verdict:
        """Run the chain on one platform sample received at ``now_ns``; accepting it advances the references."""
        verdict = self._stamp_verdict(sample, now_ns)
        if verdict is not None:
            return verdict
        if self.chain.use_base_orientation and self.base is None:
            return Verdict("no_base", "no valid base pose yet")
        base_position, base_quaternion = self.base if self.chain.use_base_orientation else (self.base_position, None)
        chiee = mocap.world_to_planar(base_position, sample.position, sample.quaternion, self.chain, base_quaternion)
        problem = self.config.workspace.problem(chiee)
        if problem:
            return Verdict("workspace", problem)
        if self.last_chiee is not None:
            problem = mocap.jump_problem(self.last_chiee, chiee, (sample.stamp_ns - self.last_stamp_ns) * 1e-9,
                                         self.config.max_speed, self.config.max_angular_speed)
            if problem:
                return Verdict("jump", problem)
        self.last_stamp_ns, self.last_chiee = sample.stamp_ns, chiee
        return Verdict(None, "", chiee)

    def _frame_problem(self, sample: Sample) -> str | None:
        """Why the sample's frame_id is not the expected one, or None."""
        if sample.frame_id == self.config.frame_id:
            return None
        return f"frame_id {sample.frame_id!r}, expected {self.config.frame_id!r}"

    def _stamp_verdict(self, sample: Sample, now_ns: int) -> Verdict | None:
        """Rejection for the frame, the values or the stamp (freshness, future, order), or None if they pass."""
        c = self.config
        problem = self._frame_problem(sample)
        if problem:
            return Verdict("frame", problem)
        if mocap.pose_problem(sample.position, sample.quaternion, norm_tol=math.inf):  # checks finiteness only
            return Verdict("non_finite", "non-finite position or quaternion")
        problem = mocap.pose_problem(sample.position, sample.quaternion, c.quaternion_tolerance)
        if problem:
            return Verdict("quaternion", problem)
        age = (now_ns - sample.stamp_ns) * 1e-9
        if c.max_age and age > c.max_age:
            return Verdict("stale", f"stamp {age:.3g} s old (max_age {c.max_age} s)")
        if -age > c.max_future:
            return Verdict("future", f"stamp {-age:.3g} s ahead of the clock (max_future {c.max_future} s)")
        if self.last_stamp_ns is not None and (self.last_stamp_ns - now_ns) * 1e-9 > c.max_future:
            self.last_stamp_ns, self.last_chiee = None, None  # the clock went back: follow the new time line
            self.time_resets += 1
        if self.last_stamp_ns is not None and sample.stamp_ns == self.last_stamp_ns:
            return Verdict("duplicate", "stamp equals the newest accepted one")
        if self.last_stamp_ns is not None and sample.stamp_ns < self.last_stamp_ns:
            behind = (self.last_stamp_ns - sample.stamp_ns) * 1e-9
            return Verdict("out_of_order", f"stamp {behind:.3g} s older than the newest accepted")
        return None

"""Check chain of the mocap bridge as a pure state machine: platform and base samples in, accept or
reject (reason).

Times are integer nanoseconds on one clock: ``now_ns`` is the bridge's clock when the sample
arrived, ``stamp_ns`` the sample's header stamp, which the mocap driver (or the simulator) sets on
that same clock. Checks of a platform sample, in this order; the first that fails rejects the sample
and leaves the state unchanged:

``frame``        header frame_id differs from the expected one (an empty or ``map`` frame is never
                 relabelled)
``non_finite``   a NaN or inf in the position or quaternion
``quaternion``   |‖q‖ − 1| > quaternion_tolerance
``stale``        now − stamp > max_age (max_age > 0)
``future``       stamp − now > max_future: a stamp the clock has not reached cannot be a measurement
``duplicate``    stamp equal to the newest accepted stamp
``out_of_order`` stamp older than the newest accepted stamp
``no_base``      the frame chain needs a measured base pose and none was accepted yet
                 (:attr:`BaseMode.WAITING`)
``base_stale``   the frame chain needs a measured base pose and the newest accepted one is more than
                 base_timeout older than this sample's stamp, or none arrived for base_timeout
                 (:attr:`BaseMode.STALE`): a stale base is never used
``workspace``    χ_ee outside the plausibility box
``jump``         χ_ee moved faster than max_speed / max_angular_speed since the newest accepted
                 sample

A base sample goes through the first seven checks (``BASE_REASONS``), with its own ordering
reference; an accepted one becomes the base pose of the frame chain.

Only an accepted sample advances its stream's ordering reference. Because a sample stamped more than
max_future ahead is rejected, one bad stamp can hold back genuine samples for at most max_future
(two 200 Hz periods by default). A reference further ahead of the clock than max_future can only
come from a clock that went back (a restarted simulation or bag); then every reference (platform and
base) is dropped, so the bridge follows the new time line from its first samples.

Silence of a stream (for :class:`Health` and :class:`BaseMode`) is measured from the later of the
newest accepted sample's arrival and its stamp: the sample proves the stream alive at both. In
lockstep simulated time the node clock moves only at timer instants, so arrival times lag by up to
one instant spacing, while the stamps do not.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hsa_core.sensing import mocap


class Rejection(enum.StrEnum):
    """Why the gate rejects a sample (module docstring); values: the bridge's /diagnostics names."""

    FRAME = "frame"
    NON_FINITE = "non_finite"
    QUATERNION = "quaternion"
    STALE = "stale"
    FUTURE = "future"
    DUPLICATE = "duplicate"
    OUT_OF_ORDER = "out_of_order"
    NO_BASE = "no_base"
    BASE_STALE = "base_stale"
    WORKSPACE = "workspace"
    JUMP = "jump"


REASONS = tuple(Rejection)
"""Rejection reasons of platform samples in check order."""

BASE_REASONS = REASONS[:7]
"""Rejection reasons of base samples in check order."""

MAX_FUTURE = 0.01
"""[s] default bound on how far a stamp may lie ahead of the clock: two periods at 200 Hz."""


class BaseMode(enum.Enum):
    """Where the frame chain's base pose comes from, and whether platform samples can be used."""

    FIXED = "fixed"  # base pose from the configuration: no base stream
    WAITING = "waiting"  # measured base, none accepted yet: platform samples rejected (no_base)
    LIVE = "live"  # measured base, newest accepted within base_timeout: used
    # measured base, none accepted for base_timeout: platform samples rejected (base_stale)
    STALE = "stale"


class Health(enum.Enum):
    """State of the accepted platform stream."""

    WAITING = "waiting"  # nothing accepted yet
    LIVE = "live"  # silence at most gap_timeout
    GAP = "gap"  # silence longer than gap_timeout
    STALE = "stale"  # silence longer than stale_timeout


@dataclass(frozen=True)
class GateConfig:
    """Bounds of the check chain (SI units; an infinite speed or a max_age of 0 disables that
    check)."""

    frame_id: str = "world"
    quaternion_tolerance: float = 0.01
    max_age: float = 0.5  # [s]
    max_future: float = MAX_FUTURE  # [s]
    max_speed: float = 4.0  # [m/s]
    max_angular_speed: float = 40.0  # [rad/s]
    workspace: mocap.WorkspaceBox = field(default_factory=mocap.WorkspaceBox)
    # [s] longest silence of the measured base before platform samples are rejected
    base_timeout: float = 0.25
    gap_timeout: float = 0.015  # [s] platform silence reported as a gap (three 200 Hz periods)
    stale_timeout: float = 0.25  # [s] platform silence reported as stale


class Sample(NamedTuple):
    """One measured body pose: stamp [ns], frame_id, world position [m] and quaternion (x, y, z,
    w)."""

    stamp_ns: int
    frame_id: str
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


class Verdict(NamedTuple):
    """Outcome of one check: reason None when accepted (chiee set for a platform sample), else the
    reason and a text."""

    reason: Rejection | None
    text: str
    chiee: np.ndarray | None = None


class MocapGate:
    """Accepts or rejects platform and base samples; keeps per stream the newest accepted stamp and
    arrival time, the newest accepted platform pose χ_ee and the newest accepted base pose."""

    def __init__(
        self,
        config: GateConfig,
        chain: mocap.MocapConfig = mocap.DEFAULT_CONFIG,
        base_position: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Checks with ``config``; frame chain ``chain``, base at ``base_position`` unless the chain
        measures it."""
        self.config = config
        self.chain = chain
        self.base_position = base_position
        # newest accepted measured base pose
        self.base: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self.base_stamp_ns: int | None = None
        self.base_at_ns: int | None = None  # clock time the newest accepted base sample arrived
        self.last_stamp_ns: int | None = None
        self.last_at_ns: int | None = None  # clock time the newest accepted platform sample arrived
        self.last_chiee: np.ndarray | None = None
        self.time_resets = 0

    def reconfigure(
        self,
        config: GateConfig,
        chain: mocap.MocapConfig,
        base_position: tuple[float, float, float],
    ) -> None:
        """New bounds and frame chain; the references (stamps, poses, arrival times) stay."""
        self.config, self.chain, self.base_position = config, chain, base_position

    def base_sample(self, sample: Sample, now_ns: int) -> Verdict:
        """Check one base sample received at ``now_ns``; accepting it makes it the base pose of the
        frame chain."""
        self._follow_clock(now_ns)
        verdict = self._stamp_verdict(sample, now_ns, self.base_stamp_ns)
        if verdict is not None:
            return verdict
        self.base = tuple(sample.position), tuple(sample.quaternion)
        self.base_stamp_ns, self.base_at_ns = sample.stamp_ns, now_ns
        return Verdict(None, "")

    def base_mode(self, now_ns: int, stamp_ns: int | None = None) -> BaseMode:
        """Whether the frame chain has a usable base pose at ``now_ns`` (see :class:`BaseMode`), for
        a platform sample stamped ``stamp_ns`` if given."""
        self._follow_clock(now_ns)
        if not self.chain.use_base_orientation:
            return BaseMode.FIXED
        if self.base is None:
            return BaseMode.WAITING
        return (
            BaseMode.STALE
            if self.base_age(now_ns, stamp_ns) > self.config.base_timeout
            else BaseMode.LIVE
        )

    def base_age(self, now_ns: int, stamp_ns: int | None = None) -> float:
        """[s] since the newest accepted base sample (later of its arrival and stamp), and at least
        its stamp's lag behind ``stamp_ns`` if given (one mocap clock: no offset; no queueing
        delay); inf if none."""
        age = _silence(now_ns, self.base_at_ns, self.base_stamp_ns)
        if stamp_ns is None or self.base_stamp_ns is None:
            return age
        return max(age, (stamp_ns - self.base_stamp_ns) * 1e-9)

    def silence(self, now_ns: int) -> float:
        """[s] since the newest accepted platform sample (later of its arrival and stamp); inf if
        none."""
        return _silence(now_ns, self.last_at_ns, self.last_stamp_ns)

    def health(self, now_ns: int) -> Health:
        """State of the accepted platform stream at ``now_ns`` (see :class:`Health`)."""
        self._follow_clock(now_ns)
        if self.last_at_ns is None:
            return Health.WAITING
        silence = self.silence(now_ns)
        if silence > self.config.stale_timeout:
            return Health.STALE
        return Health.GAP if silence > self.config.gap_timeout else Health.LIVE

    def check(self, sample: Sample, now_ns: int) -> Verdict:
        """Run the chain on one platform sample received at ``now_ns``; accepting it advances the
        references."""
        self._follow_clock(now_ns)
        verdict = self._stamp_verdict(sample, now_ns, self.last_stamp_ns)
        if verdict is not None:
            return verdict
        mode = self.base_mode(now_ns, sample.stamp_ns)
        if mode is BaseMode.WAITING:
            return Verdict(Rejection.NO_BASE, "no valid base pose yet")
        if mode is BaseMode.STALE:
            age = self.base_age(now_ns, sample.stamp_ns)
            return Verdict(
                Rejection.BASE_STALE,
                f"newest valid base pose {age:.3g} s old "
                f"(base_timeout {self.config.base_timeout} s)",
            )
        base_position, base_quaternion = (
            self.base if mode is BaseMode.LIVE else (self.base_position, None)
        )
        chiee = mocap.world_to_planar(
            base_position, sample.position, sample.quaternion, self.chain, base_quaternion
        )
        problem = self.config.workspace.problem(chiee)
        if problem:
            return Verdict(Rejection.WORKSPACE, problem)
        if self.last_chiee is not None:
            problem = mocap.jump_problem(
                self.last_chiee,
                chiee,
                (sample.stamp_ns - self.last_stamp_ns) * 1e-9,
                self.config.max_speed,
                self.config.max_angular_speed,
            )
            if problem:
                return Verdict(Rejection.JUMP, problem)
        self.last_stamp_ns, self.last_at_ns, self.last_chiee = sample.stamp_ns, now_ns, chiee
        return Verdict(None, "", chiee)

    def _follow_clock(self, now_ns: int) -> None:
        """Drop every reference if one lies more than max_future ahead of the clock (the clock went
        back)."""
        ahead = max(
            (
                t
                for t in (self.last_stamp_ns, self.last_at_ns, self.base_stamp_ns, self.base_at_ns)
                if t is not None
            ),
            default=None,
        )
        if ahead is not None and (ahead - now_ns) * 1e-9 > self.config.max_future:
            self.last_stamp_ns = self.last_at_ns = self.last_chiee = None
            self.base = self.base_stamp_ns = self.base_at_ns = None
            self.time_resets += 1

    def _stamp_verdict(self, sample: Sample, now_ns: int, last_ns: int | None) -> Verdict | None:
        """Rejection for the frame, the values or the stamp (freshness, future, order against
        ``last_ns``), or None if they pass."""
        c = self.config
        if sample.frame_id != c.frame_id:
            return Verdict(
                Rejection.FRAME, f"frame_id {sample.frame_id!r}, expected {c.frame_id!r}"
            )
        if mocap.pose_problem(
            sample.position, sample.quaternion, norm_tol=math.inf
        ):  # checks finiteness only
            return Verdict(Rejection.NON_FINITE, "non-finite position or quaternion")
        problem = mocap.pose_problem(sample.position, sample.quaternion, c.quaternion_tolerance)
        if problem:
            return Verdict(Rejection.QUATERNION, problem)
        age = (now_ns - sample.stamp_ns) * 1e-9
        if c.max_age and age > c.max_age:
            return Verdict(Rejection.STALE, f"stamp {age:.3g} s old (max_age {c.max_age} s)")
        if -age > c.max_future:
            return Verdict(
                Rejection.FUTURE,
                f"stamp {-age:.3g} s ahead of the clock (max_future {c.max_future} s)",
            )
        if last_ns is not None and sample.stamp_ns == last_ns:
            return Verdict(Rejection.DUPLICATE, "stamp equals the newest accepted one")
        if last_ns is not None and sample.stamp_ns < last_ns:
            behind = (last_ns - sample.stamp_ns) * 1e-9
            return Verdict(
                Rejection.OUT_OF_ORDER, f"stamp {behind:.3g} s older than the newest accepted"
            )
        return None


def _silence(now_ns: int, at_ns: int | None, stamp_ns: int | None) -> float:
    """[s] from the later of an arrival time and a stamp to now; inf without a sample."""
    return math.inf if at_ns is None else (now_ns - max(at_ns, stamp_ns)) * 1e-9

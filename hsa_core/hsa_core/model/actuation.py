"""Virtual-rod twists φ ↔ motor angles ψ ↔ Dynamixel ticks, and software goal limits (spec §7–§8).

Conventions (planning_and_control.md §7):

* Motor m drives virtual rod r(m) (0-based: rod 1 = index 0). By default motors [21, 22, 23, 24]
  drive rods [2, 2, 1, 1], with rod handedness ρ = [+1, −1, +1, −1] and control handedness h = [+1,
  +1].
* φ → ψ: ψ_m = φ_r(m) · h_r(m) · ρ_m, i.e. [+φ₂, −φ₂, +φ₁, −φ₁] by default.
* ψ → φ: φ_i = h_i · mean over the motors m of rod i of ρ_m ψ_m (the mean of the two motors of a
  pair).
* ψ → ticks: goal = neutral + trunc(ψ · 2048/π) as int32 (4096 ticks per revolution, truncation
  towards zero). A guard of 1e-6 tick is added away from zero before truncating, so that ticks → ψ →
  ticks is exact despite floating-point round-off (ψ·2048/π of an exact tick count can come out 1
  ulp below the integer).
* ticks → ψ: ψ = (ticks − neutral) · π/2048. Extended-position (multi-turn) mode: ticks never wrap.
* Limits (``MotorLimits``): the goal of motor m is clamped to neutral_m + s_m·[0, φ_max]·2048/π,
  widened by ``margin`` on both ends, where s_m = h_r(m)·ρ_m is the sign of the motor; the bounds
  are rounded outwards to whole ticks so the clamped goal is never outside the configured interval.
  The Max/Min Position Limit registers do not apply in extended-position mode, so this clamp is the
  only limit.
* Rate limit (``limit_goal_rate``; on the node clock ``GoalRateLimiter``): each goal moves by at
  most ⌊max_rate · dt · 2048/π⌋ ticks from the previous goal. The default ``DEFAULT_MAX_GOAL_RATE``
  is twice the MX-28's no-load speed (55 rev/min at 12 V, ROBOTIS e-Manual; spec identification.md
  §2.2): no motion of the servo can need a faster goal, a flood of full-range swings cannot.
* Absolute limits: the neutral ticks behind ``MotorLimits`` are configured (parameter or persisted
  calibration file), never taken from a value read at start. ``neutral_check`` decides whether a
  start may enable torque; ``accept_read_neutral`` lets a read neutral only refine the φ map within
  a tolerance of the configured one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

TICKS_PER_RAD = 2048.0 / math.pi
RAD_PER_TICK = math.pi / 2048.0
# rad/s: 55 rev/min at 12 V (ROBOTIS e-Manual, MX-28(2.0))
MX28_NO_LOAD_SPEED = 55.0 * 2.0 * math.pi / 60.0
# rad/s ≈ 11.5: above any speed the servo can execute
DEFAULT_MAX_GOAL_RATE = 2.0 * MX28_NO_LOAD_SPEED
_TRUNC_GUARD = 1e-6  # ticks


def angles_to_ticks(psi: ArrayLike, neutral_ticks: ArrayLike) -> np.ndarray:
    """Goal ticks neutral + trunc(ψ·2048/π) (int32) for motor angles ψ [rad]; ValueError if not
    finite or not int32."""
    offset = truncate_ticks(np.asarray(psi, dtype=np.float64) * TICKS_PER_RAD)
    if not np.all(
        np.abs(offset) < 2**31
    ):  # also catches NaN, which would otherwise cast to an arbitrary integer
        raise ValueError(f"motor angles {psi} rad are not finite or exceed the int32 tick range")
    ticks = np.asarray(neutral_ticks, dtype=np.int64) + offset.astype(np.int64)
    if np.any((ticks < -(2**31)) | (ticks >= 2**31)):
        raise ValueError("goal ticks exceed the int32 range")
    return ticks.astype(np.int32)


def truncate_ticks(raw: ArrayLike, xp=np):  # noqa: ANN001, ANN201 - xp: numpy or jax.numpy
    """Tick values [ticks] truncated towards zero, as goals are written (a 1e-6-tick guard keeps a
    whole tick that round-off put just below it); ``xp`` numpy, or jax.numpy to trace it."""
    return xp.trunc(raw + xp.copysign(_TRUNC_GUARD, raw))


def ticks_to_angles(ticks: ArrayLike, neutral_ticks: ArrayLike) -> np.ndarray:
    """Motor angles ψ = (ticks − neutral)·π/2048 [rad]."""
    delta = np.asarray(ticks, dtype=np.int64) - np.asarray(neutral_ticks, dtype=np.int64)
    return delta * RAD_PER_TICK


@dataclass(frozen=True)
class ServoModel:
    """How an MX-28 shaft follows its goal with torque on: at most ``max_speed_ticks_per_s``, then
    stop on the goal.

    The speed cap is the no-load speed (``MX28_NO_LOAD_SPEED``); ``time_constant_s`` > 0 adds a
    first-order lag below it (only tests use one, for a fast smooth servo). The world's servo has
    none (evidence: hsa_core.sim.world).
    """

    max_speed_ticks_per_s: float = MX28_NO_LOAD_SPEED * TICKS_PER_RAD
    time_constant_s: float = 0.0

    def step(self, position: float, goal: float, dt: float) -> tuple[float, float]:
        """Exact (step-size independent) position [ticks] and velocity [ticks/s] after ``dt``
        seconds."""
        error = goal - position
        if error == 0.0 or dt <= 0.0:
            return float(position), 0.0
        if math.isinf(self.max_speed_ticks_per_s):  # an ideal servo
            return float(goal), 0.0
        sign = math.copysign(1.0, error)
        remaining = abs(error)
        # below this error the lag is slower than the cap
        knee = self.max_speed_ticks_per_s * self.time_constant_s
        if remaining > knee:
            t_capped = (remaining - knee) / self.max_speed_ticks_per_s
            if dt <= t_capped:
                return (
                    position + sign * self.max_speed_ticks_per_s * dt,
                    sign * self.max_speed_ticks_per_s,
                )
            dt -= t_capped
            remaining = knee
        if self.time_constant_s <= 0.0:
            return float(goal), 0.0
        remaining *= math.exp(-dt / self.time_constant_s)
        if remaining < 0.5:
            return float(goal), 0.0
        return goal - sign * remaining, sign * remaining / self.time_constant_s


@dataclass(frozen=True)
class MotorMap:
    """Wiring of the 4 motors to the 2 virtual rods, their handedness, neutral ticks and the twist
    limit ``phi_max`` [rad] of every motor's goal (no default: the parameter set's
    ``PhiLimit.motor``, via ``Wiring.motor_map``)."""

    neutral_ticks: tuple[int, ...] = (0, 0, 0, 0)
    ids: tuple[int, ...] = (21, 22, 23, 24)
    rod: tuple[int, ...] = (1, 1, 0, 0)
    rho: tuple[int, ...] = (1, -1, 1, -1)
    h: tuple[int, ...] = (1, 1)
    margin: float = 0.02
    phi_max: float = field(kw_only=True)

    def __post_init__(self) -> None:
        """Validate sizes, signs and limits."""
        check_wiring(self.neutral_ticks, self.ids, self.rod, self.rho, self.h)
        if not (self.phi_max > 0.0 and self.margin >= 0.0):
            raise ValueError("need phi_max > 0 and margin >= 0")

    @cached_property
    def sign(self) -> np.ndarray:
        """Sign s_m = h_r(m)·ρ_m of each motor: ψ_m = s_m·φ_r(m)."""
        return np.asarray(self.h)[list(self.rod)] * np.asarray(self.rho)

    @cached_property
    def _rod_index(self) -> np.ndarray:
        """Rod index r(m) of each motor as an index array."""
        return np.asarray(self.rod)

    @cached_property
    def _motors_to_rods(self) -> np.ndarray:
        """Matrix (n_rods, n_motors) averaging s_m ψ_m over the motors of each rod."""
        member = self._rod_index[None, :] == np.arange(len(self.h))[:, None]
        return member * self.sign / member.sum(axis=1, keepdims=True)

    def motor_angles(self, phi: ArrayLike) -> np.ndarray:
        """Motor angles ψ (n_motors,) [rad] for virtual-rod twists φ (n_rods,) [rad]."""
        return np.asarray(phi, dtype=np.float64)[self._rod_index] * self.sign

    def rod_twists(self, psi: ArrayLike) -> np.ndarray:
        """Virtual-rod twists φ (n_rods,) [rad]: mean of s_m·ψ_m over the motors of each rod."""
        return self._motors_to_rods.dot(np.asarray(psi, dtype=np.float64))

    def goal_offsets(self, phi: ArrayLike, xp=np):  # noqa: ANN001, ANN201 - xp: numpy or jax.numpy
        """Goal ticks minus neutral for twists φ [rad], truncated as :meth:`goal_ticks` writes them,
        as floats and without range checks; ``xp`` numpy, or jax.numpy to trace it (the batched
        closed loop)."""
        return truncate_ticks(
            xp.asarray(phi)[self._rod_index] * xp.asarray(self.sign, dtype=float) * TICKS_PER_RAD,
            xp,
        )

    def goal_ticks(self, phi: ArrayLike) -> np.ndarray:
        """Unclamped Dynamixel goal ticks (int32) for twists φ [rad]."""
        return angles_to_ticks(self.motor_angles(phi), self.neutral_ticks)

    def present_twists(self, ticks: ArrayLike) -> np.ndarray:
        """Virtual-rod twists φ [rad] from present motor ticks."""
        return self.rod_twists(ticks_to_angles(ticks, self.neutral_ticks))

    def neutral_deviation(self, present_ticks: ArrayLike) -> np.ndarray:
        """Present minus stored neutral angle per motor [rad], for the start-up check of spec §7."""
        return ticks_to_angles(present_ticks, self.neutral_ticks)


def check_wiring(
    neutral_ticks: tuple[int, ...],
    ids: tuple[int, ...],
    rod: tuple[int, ...],
    rho: tuple[int, ...],
    h: tuple[int, ...] = (1, 1),
) -> None:
    """ValueError unless there is one entry per motor, distinct IDs, every rod driven and signs
    ±1."""
    n = len(ids)
    if not (len(neutral_ticks) == len(rod) == len(rho) == n) or len(set(ids)) != n:
        raise ValueError("ids, neutral_ticks, rod and rho need one distinct entry per motor")
    if set(rod) != set(range(len(h))):
        raise ValueError(f"rod must use every rod index 0 … {len(h) - 1}, got {rod}")
    if any(s not in (-1, 1) for s in (*rho, *h)):
        raise ValueError("rho and h entries must be +1 or -1")


@dataclass(frozen=True, eq=False)
class MotorLimits:
    """Per-motor goal bounds [lower, upper] in ticks derived from a MotorMap; ``clamp`` never leaves
    them."""

    lower: np.ndarray = field(repr=False)
    upper: np.ndarray = field(repr=False)

    @classmethod
    def from_map(cls, motor_map: MotorMap) -> MotorLimits:
        """Bounds neutral + s_m·[0, φ_max]·2048/π ± margin, rounded outwards to whole ticks."""
        neutral = np.asarray(motor_map.neutral_ticks, dtype=np.int64)
        lo_rad = np.where(motor_map.sign > 0, 0.0, -motor_map.phi_max) - motor_map.margin
        hi_rad = np.where(motor_map.sign > 0, motor_map.phi_max, 0.0) + motor_map.margin
        lower = neutral + np.floor(lo_rad * TICKS_PER_RAD).astype(np.int64)
        upper = neutral + np.ceil(hi_rad * TICKS_PER_RAD).astype(np.int64)
        lower, upper = lower.astype(np.int32), upper.astype(np.int32)
        lower.setflags(write=False)
        upper.setflags(write=False)
        return cls(lower, upper)

    def clamp(self, goal_ticks: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Goals clamped into [lower, upper] (int32) and a per-motor flag of which were changed."""
        goal = np.asarray(goal_ticks, dtype=np.int64)
        clamped = np.clip(goal, self.lower, self.upper)
        return clamped.astype(np.int32), clamped != goal

    def contains(self, ticks: ArrayLike) -> np.ndarray:
        """Per-motor flag: ticks within [lower, upper]."""
        ticks = np.asarray(ticks, dtype=np.int64)
        return (ticks >= self.lower) & (ticks <= self.upper)


def limit_goal_rate(
    previous_goal: ArrayLike, new_goal: ArrayLike, dt: float, max_rate: float
) -> np.ndarray:
    """New goal ticks (int32) moved at most ⌊max_rate [rad/s] · dt [s] · 2048/π⌋ ticks from the
    previous goal."""
    if not (dt >= 0.0 and max_rate > 0.0):
        raise ValueError(f"need dt >= 0 and max_rate > 0, got dt={dt}, max_rate={max_rate}")
    max_step = math.floor(max_rate * dt * TICKS_PER_RAD)
    previous = np.asarray(previous_goal, dtype=np.int64)
    step = np.clip(np.asarray(new_goal, dtype=np.int64) - previous, -max_step, max_step)
    return (previous + step).astype(np.int32)


def neutral_check(deviation: ArrayLike, tolerance: float, held: bool) -> str | None:
    """Why a start must not enable torque at this deviation [rad] from the configured neutral, or
    None.

    At rest the present positions must lie within ``tolerance`` of the configured neutral. A twisted
    pose is accepted only while ``held``: every servo still had torque on when the driver connected,
    so the servos have not been power-cycled since a driver enabled them at a checked pose and the
    calibration still applies (a driver restart).
    """
    deviation = np.asarray(deviation, dtype=np.float64)
    if held or np.all(np.abs(deviation) <= tolerance):
        return None
    return (
        "present positions deviate from the configured neutral ticks by "
        f"{np.round(deviation, 3).tolist()} rad "
        f"(tolerance {tolerance} rad) and the servos were not held: untwist the robot or re-home"
    )


def accept_read_neutral(
    read_ticks: ArrayLike, configured_ticks: ArrayLike, tolerance: float
) -> str | None:
    """Why neutral ticks read at start must not be used for the φ map, or None: they must lie within
    ``tolerance`` [rad] of the configured neutral (the limits stay on the configured neutral either
    way)."""
    deviation = ticks_to_angles(read_ticks, configured_ticks)
    if np.all(np.abs(deviation) <= tolerance):
        return None
    return (
        f"read neutral ticks {np.asarray(read_ticks).tolist()} deviate from the configured neutral "
        f"ticks by {np.round(deviation, 3).tolist()} rad (tolerance {tolerance} rad)"
    )


@dataclass
class RejectionLog:
    """Throttle for the log of repeated rejected or clipped commands: the first of a kind at once,
    then one summary line per ``period`` [s] with the count since the last line (times are passed
    in, any monotonic clock)."""

    period: float = 5.0
    _last: dict[str, float] = field(default_factory=dict)
    _pending: dict[str, int] = field(default_factory=dict)

    def record(self, kind: str, detail: str, now: float) -> str | None:
        """Count one ``kind`` event; the line to log now, or None while throttled."""
        self._pending[kind] = self._pending.get(kind, 0) + 1
        last = self._last.get(kind)
        if last is not None and now - last < self.period:
            return None
        count = self._pending.pop(kind)
        self._last[kind] = now
        if last is None:
            return f"{kind} phi_cmd: {detail} (repeats are logged at most every {self.period:g} s)"
        return f"{count} {kind} phi_cmd in the last {now - last:.1f} s, latest: {detail}"


@dataclass
class GoalRateLimiter:
    """Goal-rate limit that is order-independent within one clock instant.

    A write at time ``now`` may move the goal at most ``max_rate · min(now − t_a, period)`` from the
    goal in force at ``t_a``, the last EARLIER instant at which a goal was written. Several writes
    at the same instant (the cycle timer and a ``phi_cmd`` arriving in the same simulated instant,
    in either order) are all measured from that same goal, so the last target of the instant alone
    decides the final goal. On the wall clock every write has its own instant and this is the plain
    "time since the last write" limit.
    """

    # t_a: the last instant before the current one at which a goal was written
    _anchor_time: float = 0.0
    _anchor_goal: np.ndarray | None = None  # the goal in force at the end of t_a
    _time: float = 0.0  # the instant of the latest write
    _goal: np.ndarray | None = None  # the latest goal written

    def reset(self, goal: ArrayLike) -> None:
        """Torque came on holding ``goal``: it counts as in force since long ago, so the first write
        may move it by a full period's step (the held goal needs no ramp-in)."""
        held = np.asarray(goal, dtype=np.int64)
        self._anchor_time, self._anchor_goal, self._time, self._goal = (
            -math.inf,
            held,
            -math.inf,
            held,
        )

    @property
    def goal(self) -> np.ndarray | None:
        """The latest goal written (or held since ``reset``), None before the first reset."""
        return self._goal

    def limited(
        self,
        target: ArrayLike,
        now: float,
        max_rate: float,
        period: float,
        clamp: Callable[[np.ndarray], np.ndarray] = lambda g: g,
    ) -> np.ndarray:
        """The goal a write of ``target`` at ``now`` may set ([ticks]); ``max_rate`` [rad/s] 0 = no
        limit.

        ``clamp`` maps the rate-limited goal back into the absolute goal limits.
        """
        if self._goal is None:
            raise RuntimeError("GoalRateLimiter.limited before reset: no goal in force")
        target = np.asarray(target, dtype=np.int64)
        if max_rate <= 0.0:
            return target
        base_time, base_goal = (
            (self._anchor_time, self._anchor_goal)
            if now == self._time
            else (self._time, self._goal)
        )
        # a clock that jumped back allows no motion at that instant
        dt = min(max(now - base_time, 0.0), period)
        return np.asarray(clamp(limit_goal_rate(base_goal, target, dt, max_rate)), dtype=np.int64)

    def written(self, goal: ArrayLike, now: float) -> None:
        """Record that ``goal`` was written at ``now`` (a new instant makes the previous one the
        anchor)."""
        if now != self._time:
            self._anchor_time, self._anchor_goal = self._time, self._goal
        self._time, self._goal = now, np.asarray(goal, dtype=np.int64)

"""Physical plausibility of the controller's inputs: setpoints, states and sample delays,
ROS-free.

* `configuration_problem` / `state_problem`: magnitude gates on q, q_dot, chiee, chiee_dot. The
  bounds are loose physical limits (`q_bounds`: a bend of at most pi/2 over the rod length l,
  strains within +-50 % / -50..+100 %), far outside every pose the robot can reach, so they only
  catch absurd values (1e9, 1e308) before they reach any equation.
* `SetpointValidator`: a setpoint must also be an equilibrium of the model under its own phi^ss,
  i.e.
  ||G + K - alpha||(q^d, phi^ss) <= residual_tol (the planner's own acceptance threshold by
  default), with phi^ss in [0, phi_max] and chiee^d = FK(q^d) within pose_tol. Together this puts
  q^d inside the workspace (an equilibrium under an admissible twist) and phi^ss consistent with
  q^d. The two model functions are compiled once, in the constructor.
* `DelayGate`: drops a sample that arrives much later, relative to its stamp, than the promptest
  sample of the recent stream (e.g. one held in a queue while its consumer was stalled), without an
  absolute clock comparison, so it works with recorded stamps as well.
"""

from __future__ import annotations

import enum
import math
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import HsaParams
from hsa_core.refusal import Refusal, StateRejection
from hsa_core.task.planning import MAX_OPTIMALITY_ERROR, Setpoint

MAX_BEND = 0.5 * math.pi
"""Plausible |kappa_be| l [rad]: a bend of at most pi/2 over the rods (the paper's workspace needs <
0.4 rad)."""
SIGMA_LOW = np.array([-0.5, -0.5])
SIGMA_HIGH = np.array([0.5, 1.0])
"""Plausible [sigma_sh, sigma_ax] relative to xi_eq: shear within +-50 %, axial strain within -50
%..+100 % (the paper's workspace needs |sigma_sh| < 0.03 and sigma_ax in 0.19..0.35)."""
Q_DOT_MAX = np.array([1e3, 1e2, 1e2])
"""Plausible |q_dot| [rad/(m s), 1/s, 1/s]: 40x the fastest servo-driven motion of the robot."""
CHIEE_MAX = np.array([0.5, 0.5, math.pi])
"""Plausible |chiee| [m, m, rad] in {0}: the robot is 0.13 m tall."""
CHIEE_DOT_MAX = np.array([10.0, 10.0, 1e2])
"""Plausible |chiee_dot| [m/s, m/s, rad/s]."""
POSE_TOLERANCE = 1e-4
"""Default tolerance on ||chiee^d - FK(q^d)|| [m, rad]: 0.1 mm, far above rounding, far below the
paper's errors."""


class SetpointRejection(enum.StrEnum):
    """Why a setpoint is refused (the controller's /diagnostics counters)."""

    MALFORMED = "malformed"
    UNDECODABLE = "undecodable"
    OPTIMALITY = f"optimality error outside [0, {MAX_OPTIMALITY_ERROR:g}]"
    NON_FINITE_Q = "non-finite q"
    IMPLAUSIBLE_Q = "implausible q"
    NON_FINITE_CHIEE_DES = "non-finite chiee_des"
    IMPLAUSIBLE_CHIEE_DES = "implausible chiee_des"
    NON_FINITE_PHI_SS = "non-finite phi_ss"
    IMPLAUSIBLE_PHI_SS = "implausible phi_ss"
    NOT_EQUILIBRIUM = "phi_ss not an equilibrium at q_des"
    POSE_MISMATCH = "chiee_des differs from FK(q_des)"
    LAW = "refused by the control law"  # hsa_core.controller.control.Controller.set_setpoint raised


_POSE = (StateRejection.NON_FINITE_POSE, StateRejection.IMPLAUSIBLE_POSE)
_RATES = (StateRejection.NON_FINITE_RATES, StateRejection.IMPLAUSIBLE_RATES)


def _out_of(
    name: str,
    values: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    reasons: tuple[enum.Enum, enum.Enum],
) -> Refusal | None:
    """Refusal (``reasons``: non-finite, implausible) if values are outside [low, high], or None."""
    non_finite, implausible = reasons
    if not np.all(np.isfinite(values)):
        return Refusal(non_finite, f"non-finite {name}: {values.tolist()}")
    if np.any(values < low) or np.any(values > high):
        bounds = f"(bounds {low.tolist()}..{high.tolist()})"
        return Refusal(implausible, f"implausible {name}: {values.tolist()} {bounds}")
    return None


def q_bounds(params: HsaParams) -> tuple[np.ndarray, np.ndarray]:
    """Plausible q = [kappa_be [rad/m], sigma_sh, sigma_ax] of the model: |kappa_be| <= MAX_BEND /
    l, SIGMA_* bounds."""
    kappa_max = MAX_BEND / float(params.l)
    return np.concatenate([[-kappa_max], SIGMA_LOW]), np.concatenate([[kappa_max], SIGMA_HIGH])


def configuration_problem(q: ArrayLike, bounds: tuple[np.ndarray, np.ndarray]) -> Refusal | None:
    """Why q is not a plausible configuration (non-finite or outside `q_bounds`), or None."""
    return _out_of(
        "q",
        np.asarray(q, dtype=np.float64),
        *bounds,
        (SetpointRejection.NON_FINITE_Q, SetpointRejection.IMPLAUSIBLE_Q),
    )


def state_problem(
    bounds: tuple[np.ndarray, np.ndarray],
    q: ArrayLike,
    q_dot: ArrayLike,
    chiee: ArrayLike,
    chiee_dot: ArrayLike,
    velocity_valid: bool,
) -> Refusal | None:
    """Why a measured state must not reach the control law, or None: "<non-finite|implausible> <pose
    or configuration|rates>: <detail>" (:class:`StateRejection`). The rates are checked only when
    velocity_valid (they are NaN by contract else)."""
    pose = _out_of("q", np.asarray(q, dtype=np.float64), *bounds, _POSE) or _out_of(
        "chiee", np.asarray(chiee, dtype=np.float64), -CHIEE_MAX, CHIEE_MAX, _POSE
    )
    if pose is not None:
        return Refusal.of(pose.reason, pose)
    if velocity_valid:
        rates = _out_of(
            "q_dot", np.asarray(q_dot, dtype=np.float64), -Q_DOT_MAX, Q_DOT_MAX, _RATES
        ) or _out_of(
            "chiee_dot",
            np.asarray(chiee_dot, dtype=np.float64),
            -CHIEE_DOT_MAX,
            CHIEE_DOT_MAX,
            _RATES,
        )
        if rates is not None:
            return Refusal.of(rates.reason, rates)
    return None


@jax.jit
def _consistency(
    params: HsaParams, q_des: jax.Array, phi_ss: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """||G + K - alpha|| at (q^d, phi^ss) and FK(q^d)."""
    residual = jnp.linalg.norm(dynamics.static_residual(params, q_des, phi_ss))
    return residual, kinematics.end_effector_pose(params, q_des)


class SetpointValidator:
    """Checks a setpoint against the model: plausible, finite, phi^ss admissible and an equilibrium
    at q^d."""

    def __init__(
        self,
        params: HsaParams,
        residual_tol: float = MAX_OPTIMALITY_ERROR,
        pose_tol: float = POSE_TOLERANCE,
    ) -> None:
        """Keep the model and tolerances, compile the residual and FK once."""
        if not (residual_tol > 0.0 and pose_tol > 0.0):
            raise ValueError(
                f"tolerances must be > 0, got residual_tol={residual_tol!r}, pose_tol={pose_tol!r}"
            )
        self.params = params
        self.residual_tol = float(residual_tol)
        self.pose_tol = float(pose_tol)
        self.phi_lo, self.phi_hi = params.phi_limit.box
        self.q_bounds = q_bounds(params)
        self._check(np.zeros(3), 0.5 * (self.phi_lo + self.phi_hi))

    def _check(self, q_des: np.ndarray, phi_ss: np.ndarray) -> tuple[float, np.ndarray]:
        """Residual norm at (q^d, phi^ss) and FK(q^d) as NumPy values."""
        residual, chiee = _consistency(self.params, q_des, phi_ss)
        return float(residual), np.asarray(chiee)

    def problem(self, setpoint: Setpoint) -> Refusal | None:
        """Why the setpoint must be refused ("<reason>: <detail>", :class:`SetpointRejection`), or
        None; cheap gates first, the model only for plausible values."""
        r = SetpointRejection
        try:
            chiee_des, q_des, phi_ss = (
                np.asarray(v, dtype=np.float64)
                for v in (setpoint.chiee_des, setpoint.q_des, setpoint.phi_ss)
            )
            error = float(setpoint.optimality_error)
        except (TypeError, ValueError):
            return Refusal.of(r.MALFORMED, "fields are not numbers")
        if chiee_des.shape != (3,) or q_des.shape != (3,) or phi_ss.shape != (2,):
            return Refusal.of(r.MALFORMED, "needs chiee_des (3,), q_des (3,) and phi_ss (2,)")
        if not (0.0 <= error <= MAX_OPTIMALITY_ERROR):
            return Refusal.of(r.OPTIMALITY, repr(error))
        problem = (
            configuration_problem(q_des, self.q_bounds)
            or _out_of(
                "chiee_des",
                chiee_des,
                -CHIEE_MAX,
                CHIEE_MAX,
                (r.NON_FINITE_CHIEE_DES, r.IMPLAUSIBLE_CHIEE_DES),
            )
            or _out_of(
                "phi_ss",
                phi_ss,
                self.phi_lo,
                self.phi_hi,
                (r.NON_FINITE_PHI_SS, r.IMPLAUSIBLE_PHI_SS),
            )
        )
        if problem is not None:
            return problem
        residual, chiee = self._check(q_des, phi_ss)
        if not residual <= self.residual_tol:
            return Refusal.of(
                r.NOT_EQUILIBRIUM,
                f"static residual {residual:.3g} > "
                f"{self.residual_tol:g} (phi_ss {phi_ss.tolist()}, "
                f"q_des {q_des.tolist()})",
            )
        mismatch = float(np.max(np.abs(chiee - chiee_des)))
        if not mismatch <= self.pose_tol:
            return Refusal.of(
                r.POSE_MISMATCH,
                f"by {mismatch:.3g} > {self.pose_tol:g} (chiee_des "
                f"{chiee_des.tolist()}, FK {chiee.tolist()})",
            )
        return None


class DelayGate:
    """Flags samples delayed by more than max_lag [s] beyond the promptest of the last `history`
    timely arrivals.

    latency = arrival time - stamp (any constant clock offset cancels); a sample is late when its
    latency exceeds the reference, the minimum latency of the last `history` samples that were not
    late, by more than max_lag. A late sample becomes a reference only as part of a new steady
    level: `history` late samples in a row whose latencies stay within max_lag of each other (a
    permanent latency step, e.g. a clock stepped at the source) replace the reference. A stall's
    backlog never does: its latencies fall by about a sample period per sample. Times are int
    nanoseconds.
    """

    def __init__(self, max_lag: float, history: int) -> None:
        """max_lag [s] > 0 (0 disables the gate); history [samples] >= 1."""
        if max_lag < 0.0 or history < 1:
            raise ValueError(f"max_lag must be >= 0 and history >= 1, got {max_lag!r}, {history!r}")
        self.max_lag_ns = int(max_lag * 1e9)
        # (index, latency) with increasing latencies: running min
        self._latencies: deque[tuple[int, int]] = deque()
        self._history = history
        self._index = 0  # timely samples seen
        # late samples in a row: (count, lowest, highest latency)
        self._level: tuple[int, int, int] | None = None

    def late(self, stamp_ns: int, arrival_ns: int) -> bool:
        """Record one arrival; True if it is more than max_lag behind the reference (never when
        disabled)."""
        latency = arrival_ns - stamp_ns
        if (
            self.max_lag_ns > 0
            and self._latencies
            and latency - self._latencies[0][1] > self.max_lag_ns
        ):
            count, low, high = self._level or (0, latency, latency)
            low, high = min(low, latency), max(high, latency)
            if high - low > self.max_lag_ns:  # not one level: start a new run at this sample
                count, low, high = 0, latency, latency
            if count + 1 < self._history:
                self._level = (count + 1, low, high)
                return True
            self._latencies.clear()  # a steady new level: it is the reference from now on
            latency = low
        self._level = None
        while self._latencies and self._latencies[-1][1] >= latency:
            self._latencies.pop()
        self._latencies.append((self._index, latency))
        while self._latencies[0][0] <= self._index - self._history:
            self._latencies.popleft()
        self._index += 1
        return False

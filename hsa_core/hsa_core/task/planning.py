"""Steady-state planning: desired EE position -> setpoint (chiee^d, q^d, phi^ss)
(planning_and_control.md §2).

Three planners share one projected Levenberg-Marquardt step (Marquardt scaling, active set on the
box). Parameters are traced arguments, so everything compiles once per parameter structure and a
re-calibrated sigma_a_eq does not
recompile:

* ``"static"``: bounded static inversion (§2.1). Unknowns x = [theta_ee, phi1, phi2], residual G + K
  - alpha at q = IK([x^d, y^d, theta_ee]), box theta in [-pi, pi], phi in [0, phi_max] (projected LM
  with an active set). Default for both materials: for the EPU it reproduces the rollout planner's
  phi^ss (tests/core/test_planning.py), and the box excludes the non-physical roots that unbounded
  LM finds for some EPU targets (§2.3, model.md §9.3). The whole solve runs inside
  `jax.lax.while_loop`.
* ``"rollout"``: the EPU method of §2.3. F(phi) = p_ee(q(T; phi)) after a 5 s fixed-step rollout
  from rest, with the Jacobian by forward-mode differentiation through the rollout. The LM loop is
  driven from Python (each evaluation is a rollout) and starts from the bounded static inversion,
  which is already the rollout's root to < 1e-11 m for the exp2023 step points, so a plan usually
  costs a single rollout.
* ``"equilibrium"``: the "faster equivalent" of the rollout (§2.3). F(phi) = p_ee(q_eq(phi)) with
  q_eq from a Newton solve of G + K - alpha = 0 (continuation from the previous iterate) and its
  Jacobian from the implicit-function theorem; falls back to the rollout planner when the
  equilibrium is not found or is unstable.

Every result is checked: acceptance ||r|| <= 1e-3 (§2.4), phi^ss in [0, phi_max], and a stable
equilibrium (all eigenvalues of the linearisation of [q, q_dot] with negative real part, model.md
§9.4; an unstable one is UNREACHABLE). Targets farther than a margin outside the reachable workspace
(hsa_core.task.reachability.ReachabilityRegion) are rejected in microseconds. Failures are reported
with a status, never as a silently wrong setpoint.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from hsa_core import resultcache
from hsa_core.model import dynamics, kinematics, simulation
from hsa_core.model.params import HsaParams
from hsa_core.task.reachability import ReachabilityRegion, boundary_phis


class PlannerKind(enum.StrEnum):
    """Which solver plans a setpoint (§2); values are the names on the ROS interface."""

    STATIC = "static"
    EQUILIBRIUM = "equilibrium"
    ROLLOUT = "rollout"


PLANNER_KINDS = tuple(kind.value for kind in PlannerKind)
DEFAULT_PLANNER = {"fpu": PlannerKind.STATIC, "epu": PlannerKind.STATIC}
"""Default planner per material; unknown materials use "static"."""

MAX_OPTIMALITY_ERROR = 1e-3
"""Acceptance threshold on the optimality error (§2.4)."""

ROLLOUT_DURATION = 5.0
ROLLOUT_DT = 5e-4
"""Rollout horizon and fixed step of the rollout planner [s] (§2.3)."""

ROLLOUT_FTOL = 1e-9
ROLLOUT_XTOL = 1e-10
"""Rollout planner stops at an EE error <= 1 nm (1e5 below mocap noise; phi within ~1e-7 rad of the
root) or a relative step <= 1e-10: each evaluation costs a 5 s rollout."""

_LAMBDA0 = 1e-3
_LAMBDA_MAX = 1e12
_BOUND_TOL = 1e-9
_BOUNDARY_POINTS = 32
REACH_MARGIN = 1e-2
"""Fast rejection only beyond 1 cm outside the reachable polygon [m]: nearer targets go to the
solver, which reports why they fail (PHI_OUT_OF_RANGE with the best phi) instead of a bare
UNREACHABLE."""


class PlanStatus(enum.IntEnum):
    """Outcome of a planning request; values match hsa_msgs/srv/PlanSetpoint STATUS_*."""

    OK = 0
    UNREACHABLE = 1
    PHI_OUT_OF_RANGE = 2
    NOT_CONVERGED = 3
    INVALID_REQUEST = 4


@dataclasses.dataclass(frozen=True, eq=False)
class Setpoint:
    """Planner output consumed by the controllers: chiee^d (3,), q^d (3,) relative to xi_eq, phi^ss
    (2,), ||r||."""

    chiee_des: np.ndarray
    q_des: np.ndarray
    phi_ss: np.ndarray
    optimality_error: float


@dataclasses.dataclass(frozen=True)
class PlanResult:
    """Result of one planning request: status and reason, the setpoint if successful, solver
    statistics."""

    success: bool
    status: PlanStatus
    message: str
    setpoint: Setpoint | None
    optimality_error: float
    iterations: int
    solve_time_s: float
    planner: PlannerKind


class _LmState(NamedTuple):
    """Carry of the Levenberg-Marquardt loop (w: fixed row weights, set from the Jacobian at x0)."""

    x: Array
    r: Array
    J: Array
    aux: Any
    w: Array
    lam: Array
    it: Array
    done: Array


ResidualAndJacobian = Callable[[Array, Any], tuple[Array, Array, Any]]


def _lm_init(x0: Array, aux0: Any, lo: Array, hi: Array, n_res: int) -> _LmState:
    """Initial carry: x0 projected into the box; the first iteration evaluates it."""
    x0 = jnp.clip(jnp.asarray(x0, dtype=jnp.float64), lo, hi)
    return _LmState(
        x0,
        jnp.full(n_res, jnp.inf),
        jnp.zeros((n_res, x0.shape[0])),
        aux0,
        jnp.ones(n_res),
        jnp.asarray(_LAMBDA0),
        jnp.asarray(0),
        jnp.asarray(False),
    )


def _lm_propose(s: _LmState, lo: Array, hi: Array) -> tuple[Array, Array]:
    """Trial point of a projected LM step (Marquardt scaling, variables at an active bound frozen);
    x0 first."""
    rs, Js = s.w * s.r, s.w[:, None] * s.J
    g = Js.T @ rs
    H = Js.T @ Js
    free = ~(((s.x <= lo) & (g > 0.0)) | ((s.x >= hi) & (g < 0.0)))
    d = jnp.diag(H)
    d = jnp.maximum(d, 1e-12 * jnp.max(d))
    Hf = jnp.where(free[:, None] & free[None, :], H + s.lam * jnp.diag(d), jnp.eye(s.x.shape[0]))
    dx = -jnp.linalg.solve(Hf, jnp.where(free, g, 0.0))
    return jnp.where(s.it == 0, s.x, jnp.clip(s.x + dx, lo, hi)), dx


def _lm_accept(
    s: _LmState, x_t: Array, dx: Array, r_t: Array, J_t: Array, a_t: Any, ftol: float, xtol: float
) -> tuple[_LmState, Array]:
    """Accept the trial if it lowers the weighted ||r||^2 and update lambda and the stop flag; also
    returns `ok`.

    Stops at ||r|| <= ftol, a step <= xtol (xtol + ||x||) or lambda > 1e12. The row weights
    1/||J_i|| are fixed at x0; they balance the mixed units of the residual (N m^2 vs N m) without
    moving the root.
    """
    first = s.it == 0
    row_norm = jnp.linalg.norm(J_t, axis=1)
    w = jnp.where(
        first, jnp.where(jnp.isfinite(row_norm) & (row_norm > 0.0), 1.0 / row_norm, 1.0), s.w
    )
    f, f_t = jnp.sum((w * s.r) ** 2), jnp.sum((w * r_t) ** 2)
    ok = jnp.isfinite(f_t) & jnp.all(jnp.isfinite(J_t)) & (first | (f_t < f))
    x, r, J, aux = jax.tree_util.tree_map(
        lambda new, old: jnp.where(ok, new, old), (x_t, r_t, J_t, a_t), (s.x, s.r, s.J, s.aux)
    )
    lam = jnp.where(first, s.lam, jnp.where(ok, s.lam * 0.1, s.lam * 10.0))
    converged = (
        (jnp.linalg.norm(r) <= ftol)
        | (~first & (jnp.linalg.norm(x_t - s.x) <= xtol * (xtol + jnp.linalg.norm(x))))
        | (lam > _LAMBDA_MAX)
        | (~first & ~jnp.all(jnp.isfinite(dx)))
    )
    return _LmState(x, r, J, aux, w, lam, s.it + 1, (first & ~ok) | converged), ok


def _levenberg_marquardt(
    fun: ResidualAndJacobian, x0: Array, aux0: Any, lo: Array, hi: Array, max_iter: ArrayLike
) -> _LmState:
    """Projected LM inside lax.while_loop; fun(x, aux) -> (r, J, aux), aux (e.g. the configuration)
    carried along.

    The first iteration evaluates x0, so `fun` is traced once (half the compile time of a separate
    initial call).
    """
    n_res = jax.eval_shape(fun, jnp.asarray(x0, dtype=jnp.float64), aux0)[0].shape[0]

    def body(s: _LmState) -> _LmState:
        x_t, dx = _lm_propose(s, lo, hi)
        r_t, J_t, a_t = fun(x_t, s.aux)
        return _lm_accept(s, x_t, dx, r_t, J_t, a_t, 1e-15, 1e-14)[0]

    return jax.lax.while_loop(
        lambda s: ~s.done & (s.it < max_iter), body, _lm_init(x0, aux0, lo, hi, n_res)
    )


def static_inversion_residual(params: HsaParams, p_des: ArrayLike, x: ArrayLike) -> Array:
    """Static inversion residual G + K - alpha at q = IK([x^d, y^d, theta]), x = [theta, phi1, phi2]
    (§2.1)."""
    p_des, x = jnp.asarray(p_des), jnp.asarray(x)
    q = kinematics.inverse_kinematics(params, jnp.stack([p_des[0], p_des[1], x[0]]))
    return dynamics.static_residual(params, q, x[1:])


def linearization(params: HsaParams, q: ArrayLike, phi: ArrayLike) -> Array:
    """6x6 Jacobian of the [q, q_dot] dynamics at the rest point (q, 0) under constant phi (model.md
    §9.4)."""
    q, phi = jnp.asarray(q), jnp.asarray(phi)
    K_t = jax.jacfwd(dynamics.static_residual, argnums=1)(params, q, phi)
    M = dynamics.mass_matrix(params, q)
    D = dynamics.damping_matrix(params)
    # At q_dot = 0 the Coriolis term is quadratic in q_dot and drops out of the linearisation.
    lower = -jnp.linalg.solve(M, jnp.concatenate([K_t, D], axis=1))
    upper = jnp.concatenate([jnp.zeros((3, 3)), jnp.eye(3)], axis=1)
    return jnp.concatenate([upper, lower], axis=0)


def _equilibrium_lm(params: HsaParams, phi: Array, q0: Array, max_iter: ArrayLike) -> _LmState:
    """Newton/LM solve of G + K - alpha = 0 for q at fixed phi (the static forward map)."""

    def fun(q: Array, aux: Any) -> tuple[Array, Array, Any]:
        J, r = jax.jacfwd(
            lambda q_: (r_ := dynamics.static_residual(params, q_, phi), r_), has_aux=True
        )(q)
        return r, J, aux

    inf = jnp.full(3, jnp.inf)
    return _levenberg_marquardt(fun, q0, (), -inf, inf, max_iter)


@jax.jit
def static_equilibrium(params: HsaParams, phi: ArrayLike, q0: ArrayLike) -> tuple[Array, Array]:
    """Static equilibrium q(phi) from the guess q0 by Newton/LM; returns (q, ||G + K - alpha||)."""
    s = _equilibrium_lm(params, jnp.asarray(phi), jnp.asarray(q0), 100)
    return s.x, jnp.linalg.norm(s.r)


class _Solution(NamedTuple):
    """Raw output of a jitted planner solve."""

    x: Array
    residual_norm: Array
    iterations: Array
    q: Array
    chiee: Array
    lin: Array


@jax.jit
def _solve_static(
    params: HsaParams, p_des: Array, x0: Array, lo: Array, hi: Array, max_iter: Array
) -> _Solution:
    """Bounded static inversion by projected LM; x = [theta, phi1, phi2]."""

    def fun(x: Array, aux: Any) -> tuple[Array, Array, Any]:
        def res(x_: Array) -> tuple[Array, tuple[Array, Array]]:
            q = kinematics.inverse_kinematics(params, jnp.stack([p_des[0], p_des[1], x_[0]]))
            r = dynamics.static_residual(params, q, x_[1:])
            return r, (r, q)

        J, (r, q) = jax.jacfwd(res, has_aux=True)(x)
        return r, J, q

    s = _levenberg_marquardt(fun, x0, jnp.zeros(3), lo, hi, max_iter)
    chiee = jnp.stack([p_des[0], p_des[1], s.x[0]])
    return _Solution(
        s.x, jnp.linalg.norm(s.r), s.it, s.aux, chiee, linearization(params, s.aux, s.x[1:])
    )


@jax.jit
def rollout_steady_state(params: HsaParams, phi: ArrayLike) -> Array:
    """State [q, q_dot] after the planner's rollout: phi held for 5 s from rest, RK4 with dt = 5e-4
    s (§2.3)."""
    return simulation.steady_state_rollout(
        params, jnp.asarray(phi, dtype=jnp.float64), ROLLOUT_DURATION, ROLLOUT_DT
    )


@jax.jit
def _rollout_jacobian(params: HsaParams, phi: Array) -> Array:
    """dF/dphi (2x2) by forward-mode differentiation through the whole rollout (2 tangent
    directions)."""

    def forward_map(phi_: Array) -> Array:
        return kinematics.end_effector_pose(params, rollout_steady_state(params, phi_)[:3])[:2]

    return jax.jacfwd(forward_map)(phi)


_lm_propose_jit = jax.jit(_lm_propose)
_lm_accept_jit = jax.jit(_lm_accept, static_argnames=("ftol", "xtol"))
_linearization_jit = jax.jit(linearization)
_ee_pose_jit = jax.jit(kinematics.end_effector_pose)


def _solve_rollout(
    params: HsaParams,
    p_des: np.ndarray,
    phi0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    max_iter: int,
) -> _Solution:
    """Rollout planner: LM on F(phi) - p^d, F from a 5 s rollout, Jacobian by forward mode through
    the rollout.

    Same LM steps as the compiled loop, driven from Python: each evaluation costs a full rollout, so
    trial points are evaluated without the Jacobian, and the Jacobian (compiled on first use) only
    at accepted, non-final points.
    """
    s = _lm_init(phi0, jnp.zeros(3), lo, hi, 2)
    while not bool(s.done) and int(s.it) < max_iter:
        x_t, dx = _lm_propose_jit(s, lo, hi)
        q_t = rollout_steady_state(params, x_t)[:3]
        r_t = _ee_pose_jit(params, q_t)[:2] - p_des
        # The current Jacobian stands in for the trial's; the real one is computed below only if it
        # is needed.
        s, ok = _lm_accept_jit(s, x_t, dx, r_t, s.J, q_t, ftol=ROLLOUT_FTOL, xtol=ROLLOUT_XTOL)
        if bool(ok) and not bool(s.done) and int(s.it) < max_iter:
            J = _rollout_jacobian(params, s.x)
            if int(s.it) == 1:  # row weights from the Jacobian at x0, as in the compiled loop
                norms = np.linalg.norm(np.asarray(J), axis=1)
                s = s._replace(w=jnp.asarray(np.where(norms > 0.0, 1.0 / norms, 1.0)))
            s = s._replace(J=J)
    chiee = _ee_pose_jit(params, s.aux)
    return _Solution(
        s.x, jnp.linalg.norm(s.r), s.it, s.aux, chiee, _linearization_jit(params, s.aux, s.x)
    )


@jax.jit
def _solve_equilibrium(
    params: HsaParams, p_des: Array, phi0: Array, q0: Array, lo: Array, hi: Array, max_iter: Array
) -> _Solution:
    """Equilibrium planner: LM on p_ee(q_eq(phi)) - p^d, Jacobian J_ee,xy K_t^-1 A by the
    implicit-function theorem."""

    def fun(phi: Array, q_guess: Array) -> tuple[Array, Array, Any]:
        eq = _equilibrium_lm(params, phi, q_guess, 50)
        q = eq.x
        converged = jnp.linalg.norm(eq.r) <= 1e-9
        K_t = jax.jacfwd(dynamics.static_residual, argnums=1)(params, q, phi)
        A = dynamics.actuation_jacobian(params, q, phi)
        J = kinematics.end_effector_jacobian(params, q)[:2] @ jnp.linalg.solve(K_t, A)
        r = jnp.where(converged, kinematics.end_effector_pose(params, q)[:2] - p_des, jnp.nan)
        return r, J, q

    s = _levenberg_marquardt(fun, phi0, q0, lo, hi, max_iter)
    chiee = kinematics.end_effector_pose(params, s.aux)
    return _Solution(
        s.x, jnp.linalg.norm(s.r), s.it, s.aux, chiee, linearization(params, s.aux, s.x)
    )


@jax.jit
def _equilibrium_positions(params: HsaParams, phis: Array) -> tuple[Array, Array]:
    """EE positions (N, 2) and residual norms (N,) of the static equilibria for a batch of phi, from
    q = 0."""

    def one(phi: Array) -> tuple[Array, Array]:
        s = _equilibrium_lm(params, phi, jnp.zeros(3), 100)
        return kinematics.end_effector_pose(params, s.x)[:2], jnp.linalg.norm(s.r)

    return jax.vmap(one)(phis)


class Planner:
    """Setpoint planner for one parameter set: compiles at construction, then plans in milliseconds
    (static)."""

    def __init__(
        self,
        params: HsaParams,
        kind: PlannerKind | str | None = None,
        *,
        max_optimality_error: float = MAX_OPTIMALITY_ERROR,
        max_iter: int = 100,
    ) -> None:
        """Select the planner (default per material), build the reachability region and compile the
        solvers."""
        kind = DEFAULT_PLANNER.get(params.material, PlannerKind.STATIC) if kind is None else kind
        if kind not in PLANNER_KINDS:
            raise ValueError(f"unknown planner kind {kind!r}; expected one of {PLANNER_KINDS}")
        if not max_optimality_error > 0.0:
            raise ValueError(f"max_optimality_error must be > 0, got {max_optimality_error!r}")
        self.params = params
        self.kind = PlannerKind(kind)
        self.max_optimality_error = float(max_optimality_error)
        self._max_iter = np.asarray(max_iter, dtype=np.int32)
        self._phi_lo, self._phi_hi = params.phi_limit.box
        self._x_lo = np.concatenate([[-np.pi], self._phi_lo])
        self._x_hi = np.concatenate([[np.pi], self._phi_hi])
        self._phi_mid = 0.5 * (self._phi_lo + self._phi_hi)
        self._region = self._reachability_region()
        self._warm: tuple[np.ndarray, np.ndarray] | None = None
        self._compile()

    def _compile(self) -> None:
        """Compile what this planner uses without solving (max_iter = 0 is traced; the rollout is
        compiled ahead).

        The forward-mode rollout Jacobian is left to its first use: a seeded rollout solve rarely
        needs it.
        """
        p, no_iter = np.array([0.0, float(self.params.l)]), np.asarray(0, dtype=np.int32)
        x0 = np.concatenate([[0.0], self._phi_mid])
        if self.kind is not PlannerKind.EQUILIBRIUM:  # rollout: seeded by static inversion
            jax.block_until_ready(
                _solve_static(self.params, p, x0, self._x_lo, self._x_hi, no_iter)
            )
        if self.kind is PlannerKind.ROLLOUT:
            s0 = _lm_init(self._phi_mid, jnp.zeros(3), self._phi_lo, self._phi_hi, 2)
            x_t, dx = _lm_propose_jit(s0, self._phi_lo, self._phi_hi)
            _lm_accept_jit(s0, x_t, dx, s0.r, s0.J, s0.aux, ftol=ROLLOUT_FTOL, xtol=ROLLOUT_XTOL)
            rollout_steady_state.lower(self.params, self._phi_mid).compile()
            jax.block_until_ready(
                _solve_rollout(self.params, p, self._phi_mid, self._phi_lo, self._phi_hi, 0)
            )
        if self.kind is PlannerKind.EQUILIBRIUM:
            args = (self.params, p, self._phi_mid, np.zeros(3), self._phi_lo, self._phi_hi, no_iter)
            jax.block_until_ready(_solve_equilibrium(*args))

    def _reachability_region(self) -> ReachabilityRegion:
        """Reachable polygon: equilibria along the edges of the phi box
        (hsa_core.analysis.workspace), with REACH_MARGIN.

        Always built with the exact kappa rule: the exp2023 shift moves equilibria by <= 0.04 mm
        (model.md §8.3), far inside the margin, and its jump at kappa = 0 would stall the
        equilibrium solves on the phi1 = phi2 diagonal.
        """
        phis = boundary_phis(self._phi_lo, self._phi_hi, _BOUNDARY_POINTS)
        exact = (
            self.params
            if self.params.kappa_rule == "exact"
            else self.params.replace(kappa_rule="exact")
        )

        def compute() -> dict[str, np.ndarray]:
            p, res = _equilibrium_positions(exact, phis)
            return {"p": np.asarray(p), "res": np.asarray(res)}

        # the same values, kept from a last start
        found = resultcache.cached("reachability", (exact, phis), compute)
        p, res = found["p"], found["res"]
        if not np.all(np.isfinite(p)) or not np.all(res <= self.max_optimality_error):
            raise RuntimeError(
                "static equilibria on the edges of the phi box did not converge; cannot bound the "
                "workspace"
            )
        return ReachabilityRegion(p, REACH_MARGIN)

    def in_reach_region(self, p_des: ArrayLike) -> bool:
        """Fast conservative test: False only if p^d is certainly unreachable with phi in [0,
        phi_max]^2."""
        return self._region.contains(p_des)

    def reset_warm_start(self) -> None:
        """Forget the previous solution (next plan starts cold)."""
        self._warm = None

    def plan(self, p_des: ArrayLike, warm_start: bool = True) -> PlanResult:
        """Plan a setpoint for the desired EE position p^d = [x, y] in {0}; warm_start uses the
        previous solution."""
        t0 = time.perf_counter()
        try:
            p = np.asarray(p_des, dtype=np.float64)
        except (TypeError, ValueError):
            p = np.full(1, np.nan)
        if p.shape != (2,) or not np.all(np.isfinite(p)):
            return self._fail(
                PlanStatus.INVALID_REQUEST, f"p_des must be 2 finite numbers, got {p_des!r}", t0
            )
        if not self.in_reach_region(p):
            return self._fail(
                PlanStatus.UNREACHABLE, f"p_des {p.tolist()} is outside the reachable workspace", t0
            )
        warm = self._warm if warm_start else None
        sol, iterations = self._solve(p, warm)
        if warm is not None and not self._acceptable(sol):
            sol, more = self._solve(p, None)
            iterations += more
        return self._finish(p, sol, iterations, t0)

    def _solve(
        self, p: np.ndarray, warm: tuple[np.ndarray, np.ndarray] | None
    ) -> tuple[_Solution, int]:
        """Run the selected solver from the warm start (previous x*, q^d), else from the centre of
        the phi box.

        The rollout solve starts from the bounded static inversion when that succeeds: the same root
        (the 5 s rollout ends at the static equilibrium, §2.3), reached with one or two rollouts
        instead of several LM iterations.
        """
        phi0 = self._phi_mid if warm is None else warm[0][1:]
        if self.kind is PlannerKind.EQUILIBRIUM:
            q0 = np.zeros(3) if warm is None else warm[1]
            sol = _solve_equilibrium(
                self.params, p, phi0, q0, self._phi_lo, self._phi_hi, self._max_iter
            )
            if self._acceptable(sol):
                return sol, int(sol.iterations)
            rollout = _solve_rollout(
                self.params, p, phi0, self._phi_lo, self._phi_hi, self._max_iter
            )
            return rollout, int(sol.iterations) + int(rollout.iterations)
        x0 = np.concatenate([[0.0], phi0]) if warm is None else warm[0]
        sol = _solve_static(self.params, p, x0, self._x_lo, self._x_hi, self._max_iter)
        if self.kind is PlannerKind.STATIC:
            return sol, int(sol.iterations)
        seed = np.asarray(sol.x)[1:] if self._acceptable(sol) else phi0
        rollout = _solve_rollout(self.params, p, seed, self._phi_lo, self._phi_hi, self._max_iter)
        return rollout, int(sol.iterations) + int(rollout.iterations)

    def _acceptable(self, sol: _Solution) -> bool:
        """Converged within the acceptance tolerance to an in-range, stable equilibrium."""
        return (
            float(sol.residual_norm) <= self.max_optimality_error
            and self._in_range(sol)
            and _stable(sol.lin)
        )

    def _in_range(self, sol: _Solution) -> bool:
        """phi^ss inside [0, phi_max] (up to rounding)."""
        phi = np.asarray(sol.x)[-2:]
        return bool(np.all(phi >= self._phi_lo - 1e-12) and np.all(phi <= self._phi_hi + 1e-12))

    def _finish(self, p: np.ndarray, sol: _Solution, iterations: int, t0: float) -> PlanResult:
        """Classify a solve and build the PlanResult (and the warm start on success)."""
        x = np.asarray(sol.x)
        err = float(sol.residual_norm)
        phi = x[-2:]
        if not np.isfinite(err) or err > self.max_optimality_error:
            at_bound = np.any(
                np.minimum(np.abs(phi - self._phi_lo), np.abs(phi - self._phi_hi)) <= _BOUND_TOL
            )
            if np.isfinite(err) and at_bound:
                status = PlanStatus.PHI_OUT_OF_RANGE
                why = f"no equilibrium with phi in [0, phi_max]; best phi {phi.tolist()}"
            else:
                status, why = (
                    PlanStatus.NOT_CONVERGED,
                    "solver did not reach the acceptance tolerance",
                )
            msg = (
                f"{why} (optimality error {err:.3g} > {self.max_optimality_error:g}) for p_des "
                f"{p.tolist()}"
            )
            return self._fail(status, msg, t0, err, iterations)
        if not self._in_range(sol):
            msg = f"phi_ss {phi.tolist()} outside [0, phi_max] for p_des {p.tolist()}"
            return self._fail(PlanStatus.PHI_OUT_OF_RANGE, msg, t0, err, iterations)
        if not _stable(sol.lin):
            msg = f"the equilibrium for p_des {p.tolist()} at phi {phi.tolist()} is unstable"
            return self._fail(PlanStatus.UNREACHABLE, msg, t0, err, iterations)
        q = np.asarray(sol.q)
        setpoint = Setpoint(np.asarray(sol.chiee), q, np.clip(phi, self._phi_lo, self._phi_hi), err)
        theta = setpoint.chiee_des[2]
        self._warm = (np.concatenate([[theta], setpoint.phi_ss]), q)
        return PlanResult(
            True,
            PlanStatus.OK,
            "ok",
            setpoint,
            err,
            iterations,
            time.perf_counter() - t0,
            self.kind,
        )

    def _fail(
        self,
        status: PlanStatus,
        message: str,
        t0: float,
        err: float = float("nan"),
        iterations: int = 0,
    ) -> PlanResult:
        """A failed PlanResult; the warm start is kept (the next target may be reachable again)."""
        return PlanResult(
            False, status, message, None, err, iterations, time.perf_counter() - t0, self.kind
        )


def _stable(lin: ArrayLike) -> bool:
    """All eigenvalues of the [q, q_dot] linearisation have negative real parts."""
    eig = np.linalg.eigvals(np.asarray(lin))
    return bool(np.all(np.isfinite(eig)) and np.all(eig.real < 0.0))

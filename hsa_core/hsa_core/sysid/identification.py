"""Least-squares identification of the elastic and actuation constants from settled samples
(identification.md §3-4).

Model (identification.md §4.1, written for the two virtual rods j of the control model, each the sum
of N_PAIR = 2 identical physical rods, §4.11): with the twist strain u_j = h_j phi_j / l and e_j =
sigma_ax + roff_j kappa - sigma_a_eq,j, one physical rod of pair j carries

    f_a = (S_a_hat + C_S_a u)(e - C_eps u),   f_b = (S_b_hat + C_S_b u) kappa + S_b_sh sigma_sh,
    f_s = S_b_sh kappa + (S_sh_hat + C_S_sh u) sigma_sh,

and K - alpha = N_PAIR sum_j [f_b + roff_j f_a, f_s, f_a]. Every settled sample k satisfies the
static equilibrium G(xi_k; m_pl,k) + K - alpha = 0 (3 rows: kappa, sigma_sh, sigma_ax). All
constants are per physical rod, shared by all rods, exactly what the parameter YAML holds. Every
step is linear in its unknowns (A_k = dr_k/dPi by forward-mode differentiation, which is exact for
an affine residual; b_k = -r_k(0)):

* A: S_a_hat and S_a_hat sigma_a_eq,r (one rest strain per record r) from the phi = 0 samples of the
  elongation records, sigma_ax rows; payload variation separates the two.
* B <-> C: C_eps from the unloaded twisted elongation samples, then C_S_a from all elongation
  samples, alternated until both change by < 0.01 % (the one-pass sequence of 2023 biases C_S_a by
  ~20 %, §4.12).
* E (with D): S_b_hat, S_sh_hat, S_b_sh, C_S_b, C_S_sh and the per-side rest strains sigma_a_eq,1/2
  of every bending record, jointly from all three rows of the bending samples. D (the record's rest
  strains) enters the same rows linearly, so solving it jointly removes the order dependence of a
  separate D step.
* F: all constants and all rest strains jointly by Gauss-Newton from the sequential values, over all
  rows of every sample. The sequential steps pass their errors on (an S_a_hat error biases C_eps,
  C_S_a and the bending target); the joint fit uses every equation for every constant, and its
  covariance accounts for those couplings.

Each solve scales the columns to unit norm (condition number reported), weights each row type by the
inverse of its residual RMS from a first unweighted pass (§7 item 5), and reports standard errors
sigma^2 (A^T W A)^-1, 95 % confidence intervals (Student t) and the residual RMS per row type (§7
item 4, §8 item 4). The generalized stiffness is checked for positive definiteness over the
actuation box (§7 item 8). Geometry, masses and damping are never changed.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import yaml
from jax import Array
from numpy.typing import ArrayLike
from scipy import stats

from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import HsaParams

N_PAIR = 2
"""Physical rods per virtual rod (model.md §2)."""

ROWS = ("kappa", "sigma_sh", "sigma_ax")
"""Equation rows of one sample (units N m^2, N m, N m)."""

ELASTIC_KEYS = ("C_eps", "S_a_hat", "C_S_a", "S_b_hat", "S_sh_hat", "S_b_sh", "C_S_b", "C_S_sh")
"""Constants identified here, per physical rod (the YAML keys)."""

BENDING_KEYS = ("S_b_hat", "S_sh_hat", "S_b_sh", "C_S_b", "C_S_sh")
CONVERGENCE_RTOL = 1e-6
"""B <-> C alternation stops when C_eps and C_S_a change by less than 1e-4 % (the spec asks < 0.01
%, §4.12)."""
CONFIDENCE = 0.95


class IdentificationError(ValueError):
    """The data cannot identify what was asked (too few samples, rank deficiency); the message says
    what is missing."""


# --------------------------------------------------------------------------------------------------
# linear least squares with scaling, row-type weights and uncertainty


@dataclasses.dataclass(frozen=True)
class LinearFit:
    """One least-squares step: estimate, standard errors, 95 % interval, residuals and
    conditioning."""

    names: tuple[str, ...]
    estimate: np.ndarray
    std: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    residuals: np.ndarray
    row_types: np.ndarray
    residual_rms: dict[str, float]
    condition_number: float
    n_rows: int
    dof: int
    A: np.ndarray
    b: np.ndarray

    def value(self, name: str) -> float:
        """Estimate of the unknown `name`."""
        return float(self.estimate[self.names.index(name)])


def solve_linear(
    A: ArrayLike,
    b: ArrayLike,
    names: Sequence[str],
    row_types: Sequence[str] | None = None,
    reweight: bool = True,
) -> LinearFit:
    """Solve A Pi = b by column-scaled least squares with per-row-type weights; uncertainty from the
    residuals.

    Rows whose regressor is identically zero are dropped (identification.md §4.2 item 2). A
    rank-deficient stacked regressor raises IdentificationError naming the unknowns involved.
    """
    A, b = np.asarray(A, dtype=float), np.asarray(b, dtype=float)
    types = np.asarray(row_types if row_types is not None else ["row"] * len(b))
    keep = np.any(A != 0.0, axis=1)
    A, b, types = A[keep], b[keep], types[keep]
    n, p = A.shape
    if n < p:
        raise IdentificationError(f"{n} informative equations for {p} unknowns {list(names)}")
    scale = np.linalg.norm(A, axis=0)
    if np.any(scale == 0.0):
        raise IdentificationError(
            f"no data constrains {[nm for nm, s in zip(names, scale) if s == 0.0]}"
        )
    As = A / scale
    sv = np.linalg.svd(As, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0.0 else np.inf
    if not cond < 1e12:
        raise IdentificationError(
            f"the regressor of {list(names)} is rank deficient (scaled condition {cond:.3g})"
        )
    weights = np.ones(n)
    x = np.linalg.lstsq(As, b, rcond=None)[0]
    if reweight:
        res = b - As @ x
        for kind in np.unique(types):
            sel = types == kind
            rms = np.sqrt(np.mean(res[sel] ** 2))
            floor = 1e-12 * max(np.sqrt(np.mean(b[sel] ** 2)), 1e-300)
            weights[sel] = 1.0 / max(rms, floor)
        x = np.linalg.lstsq(As * weights[:, None], b * weights, rcond=None)[0]
    res = b - As @ x
    dof = n - p
    Aw = As * weights[:, None]
    if dof > 0:
        s2 = float(np.sum((weights * res) ** 2) / dof)
        cov = s2 * np.linalg.inv(Aw.T @ Aw) / np.outer(scale, scale)
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        half = stats.t.ppf(0.5 + CONFIDENCE / 2.0, dof) * std
    else:
        std = half = np.full(p, np.nan)
    estimate = x / scale
    rms = {str(kind): float(np.sqrt(np.mean(res[types == kind] ** 2))) for kind in np.unique(types)}
    return LinearFit(
        tuple(names),
        estimate,
        std,
        estimate - half,
        estimate + half,
        res,
        types,
        rms,
        cond,
        n,
        dof,
        A,
        b,
    )


# --------------------------------------------------------------------------------------------------
# the static model, per physical rod


def elastic_actuation_force(
    params: HsaParams,
    theta: dict[str, ArrayLike],
    sigma_a_eq: ArrayLike,
    xi: ArrayLike,
    phi: ArrayLike,
) -> Array:
    """K - alpha (3,) at strains xi for per-physical-rod constants `theta` and per-virtual-rod rest
    strains (§4.1)."""
    xi, phi = jnp.asarray(xi), jnp.asarray(phi)
    kappa = xi[0] - params.kappa_b_eq
    sigma_sh = xi[1] - params.sigma_sh_eq
    u = params.h * phi / params.l
    e = xi[2] + params.roff * xi[0] - jnp.asarray(sigma_a_eq)
    f_a = (theta["S_a_hat"] + theta["C_S_a"] * u) * (e - theta["C_eps"] * u)
    f_b = (theta["S_b_hat"] + theta["C_S_b"] * u) * kappa + theta["S_b_sh"] * sigma_sh
    f_s = theta["S_b_sh"] * kappa + (theta["S_sh_hat"] + theta["C_S_sh"] * u) * sigma_sh
    return N_PAIR * jnp.stack([jnp.sum(f_b + params.roff * f_a), jnp.sum(f_s), jnp.sum(f_a)])


@jax.jit
def gravity_at(params: HsaParams, xi: ArrayLike, m_pl: ArrayLike) -> Array:
    """G(xi; m_pl) for a batch of strains xi (N, 3) and payload masses (N,) [kg], with the params'
    payload CoG."""

    def one(x: Array, m: Array) -> Array:
        return dynamics.gravity_vector(dataclasses.replace(params, m_pl=m), x - params.xi_eq)

    return jax.vmap(one)(jnp.asarray(xi), jnp.asarray(m_pl, dtype=jnp.float64))


def dynamic_strains(params: HsaParams, xi: ArrayLike) -> Array:
    """Strains (N, 3) at which the model is evaluated (kappa shifted in the exp2023 mode; one
    variant everywhere)."""
    return jax.vmap(lambda x: kinematics.apply_kappa_rule(params, x, dynamics.KAPPA_SHIFT_DYN))(
        jnp.asarray(xi)
    )


def per_rod_constants(params: HsaParams) -> dict[str, float]:
    """The identified constants of a parameter set per physical rod (virtual-rod value / N_PAIR,
    C_eps as is)."""
    out = {}
    for key in ELASTIC_KEYS:
        value = float(np.mean(np.asarray(getattr(params, key))))
        out[key] = value if key == "C_eps" else value / N_PAIR
    return out


# --------------------------------------------------------------------------------------------------
# data: records and settled samples


@dataclasses.dataclass(frozen=True)
class Record:
    """One recorded experiment on the mocap grid: t (N,) [s], chiee (N, 3), measured phi (N, 2),
    payload (N,) [kg].

    `role` is "elongation" (phi1 = phi2; steps A-C) or "bending" (step E).
    """

    name: str
    t: np.ndarray
    chiee: np.ndarray
    phi: np.ndarray
    payload: np.ndarray
    role: str


@dataclasses.dataclass(frozen=True)
class Samples:
    """Settled samples of all records: strains xi (N, 3), phi (N, 2), payload (N,), record index
    (N,), names."""

    xi: np.ndarray
    phi: np.ndarray
    payload: np.ndarray
    record: np.ndarray
    records: tuple[str, ...]
    roles: tuple[str, ...]

    def select(self, mask: np.ndarray) -> Samples:
        """The samples where mask is true (record names kept)."""
        return Samples(
            self.xi[mask],
            self.phi[mask],
            self.payload[mask],
            self.record[mask],
            self.records,
            self.roles,
        )


@jax.jit
def _strains_from_poses(params: HsaParams, chiee: Array) -> Array:
    """xi = IK(chiee) + xi_eq for a batch of poses: the strains themselves, independent of the rest
    strains."""
    return jax.vmap(lambda c: kinematics.inverse_kinematics(params, c))(chiee) + params.xi_eq


def settled_segments(
    t: ArrayLike,
    phi: ArrayLike,
    payload: ArrayLike,
    settle: float = 2.0,
    window: float = 1.0,
    phi_tol: float = 2e-3,
) -> list[tuple[int, int]]:
    """Index ranges [a, b) of the last `window` s of every hold of constant phi and payload lasting
    >= settle + window."""
    t, phi, payload = np.asarray(t, float), np.asarray(phi, float), np.asarray(payload, float)
    change = np.any(np.abs(np.diff(phi, axis=0)) > phi_tol, axis=1) | (np.diff(payload) != 0.0)
    starts = np.concatenate([[0], np.flatnonzero(change) + 1])
    ends = np.concatenate([starts[1:], [len(t)]])
    segments = []
    for a, b in zip(starts, ends):
        t_end = t[b - 1]
        if t_end - t[a] < settle + window - 1e-9:
            continue
        first = int(np.searchsorted(t, t_end - window, side="left"))
        segments.append((max(first, a), b))
    return segments


def settled_samples(
    params: HsaParams,
    records: Sequence[Record],
    settle: float = 2.0,
    window: float = 1.0,
    phi_tol: float = 2e-3,
    max_drift: float = 2e-4,
) -> Samples:
    """One averaged sample per settled hold of every record (automatic steady state,
    identification.md §7 item 6).

    A hold counts when phi and the payload stayed constant (within phi_tol) for settle + window s;
    the strains (IK of every pose) and phi are averaged over its last `window` s. Holds whose EE
    position still drifts by more than `max_drift` [m] between the two halves of the window are
    dropped (not settled).
    """
    xi_all, phi_all, m_all, rec_all = [], [], [], []
    for index, rec in enumerate(records):
        if rec.role not in ("elongation", "bending"):
            raise IdentificationError(
                f"record {rec.name}: role must be 'elongation' or 'bending', got {rec.role!r}"
            )
        xi = np.asarray(_strains_from_poses(params, jnp.asarray(rec.chiee, dtype=jnp.float64)))
        for a, b in settled_segments(rec.t, rec.phi, rec.payload, settle, window, phi_tol):
            half = (a + b) // 2
            drift = np.linalg.norm(
                rec.chiee[half:b, :2].mean(axis=0) - rec.chiee[a:half, :2].mean(axis=0)
            )
            if b - a < 2 or drift > max_drift:
                continue
            xi_all.append(xi[a:b].mean(axis=0))
            phi_all.append(rec.phi[a:b].mean(axis=0))
            m_all.append(rec.payload[a])
            rec_all.append(index)
    if not xi_all:
        raise IdentificationError("no settled hold found in the records")
    return Samples(
        np.array(xi_all),
        np.array(phi_all),
        np.array(m_all),
        np.array(rec_all),
        tuple(r.name for r in records),
        tuple(r.role for r in records),
    )


# --------------------------------------------------------------------------------------------------
# the steps


def _theta_of(values: dict[str, float]) -> dict[str, float]:
    """All ELASTIC_KEYS from `values`, missing ones 0 (not yet identified: they multiply nothing in
    that step)."""
    return {key: float(values.get(key, 0.0)) for key in ELASTIC_KEYS}


def _record_columns(samples: Samples, records: np.ndarray) -> np.ndarray:
    """Position of each sample's record among `records` (the per-record unknown it uses)."""
    lookup = {int(r): i for i, r in enumerate(records)}
    return np.array([lookup[int(r)] for r in samples.record])


def step_a(params: HsaParams, samples: Samples) -> tuple[LinearFit, dict[int, float]]:
    """Step A: S_a_hat and S_a_hat sigma_a_eq,r from phi = 0 samples (sigma_ax rows); returns the
    fit and sigma_a_eq,r.

    At u = 0 the sigma_ax row is G_ax + N_PAIR sum_j S_a (sigma_ax + roff_j kappa) - N_PAIR n_rods
    S_a sigma_r = 0; the per-side rest strains enter only through their mean, which is what A can
    identify.
    """
    xi_d = np.asarray(dynamic_strains(params, samples.xi))
    G = np.asarray(gravity_at(params, samples.xi, samples.payload))
    records = np.unique(samples.record)
    col = _record_columns(samples, records)
    roff = np.asarray(params.roff)
    A = np.zeros((len(samples.xi), 1 + len(records)))
    A[:, 0] = N_PAIR * np.sum(xi_d[:, 2:3] + roff[None, :] * xi_d[:, 0:1], axis=1)
    A[np.arange(len(col)), 1 + col] = -N_PAIR * len(roff)
    names = ("S_a_hat", *[f"S_a_hat*sigma_a_eq[{samples.records[r]}]" for r in records])
    fit = solve_linear(A, -G[:, 2], names, ["sigma_ax"] * len(col))
    s_a = fit.estimate[0]
    return fit, {int(r): float(fit.estimate[1 + i] / s_a) for i, r in enumerate(records)}


@jax.jit
def _scalar_rows(
    params: HsaParams,
    theta: dict[str, Array],
    dz: dict[str, Array],
    xi_d: Array,
    phi: Array,
    G: Array,
    sigma: Array,
) -> tuple[Array, Array]:
    """Derivative along the constants marked in `dz` (N, 3) and value (N, 3) of G + K - alpha at
    `theta`."""

    def r(z: Array, x: Array, p: Array, g: Array, s: Array) -> Array:
        th = {key: theta[key] + z * dz[key] for key in theta}
        return g + elastic_actuation_force(params, th, s, x, p)

    jac = jax.vmap(jax.jacfwd(r), in_axes=(None, 0, 0, 0, 0))(0.0, xi_d, phi, G, sigma)
    val = jax.vmap(r, in_axes=(None, 0, 0, 0, 0))(0.0, xi_d, phi, G, sigma)
    return jac, val


def _scalar_step(
    params: HsaParams, samples: Samples, theta: dict[str, float], sigma: np.ndarray, key: str
) -> LinearFit:
    """Steps B and C: one constant `key` from the sigma_ax rows with everything else fixed (sigma:
    (N, 2) per sample)."""
    theta = {**_theta_of(theta), key: 0.0}
    dz = {k: float(k == key) for k in theta}
    xi_d = dynamic_strains(params, samples.xi)
    G = gravity_at(params, samples.xi, samples.payload)
    jac, val = (
        np.asarray(a)
        for a in _scalar_rows(
            params, theta, dz, xi_d, jnp.asarray(samples.phi), G, jnp.asarray(sigma)
        )
    )
    return solve_linear(jac[:, 2:3], -val[:, 2], (key,), ["sigma_ax"] * len(val))


def steps_b_c(
    params: HsaParams,
    samples: Samples,
    theta: dict[str, float],
    sigma_by_record: dict[int, float],
    max_passes: int = 100,
    unloaded_below: float = 1e-6,
) -> tuple[LinearFit, LinearFit, int]:
    """Steps B (C_eps, unloaded samples) and C (C_S_a, all samples) alternated to convergence;
    returns fits, passes."""
    sigma = np.array([[sigma_by_record[int(r)]] * 2 for r in samples.record])
    unloaded = samples.payload < unloaded_below
    twisted = np.any(samples.phi > 1e-3, axis=1)
    theta = {**theta, "C_S_a": theta.get("C_S_a", 0.0)}
    for passes in range(1, max_passes + 1):
        fit_b = _scalar_step(
            params, samples.select(unloaded & twisted), theta, sigma[unloaded & twisted], "C_eps"
        )
        new_c_eps = fit_b.estimate[0]
        fit_c = _scalar_step(
            params, samples.select(twisted), {**theta, "C_eps": new_c_eps}, sigma[twisted], "C_S_a"
        )
        new_c_sa = fit_c.estimate[0]
        change = max(
            abs(new_c_eps - theta.get("C_eps", 0.0)) / abs(new_c_eps),
            abs(new_c_sa - theta["C_S_a"]) / max(abs(new_c_sa), 1e-300),
        )
        theta = {**theta, "C_eps": new_c_eps, "C_S_a": new_c_sa}
        if change < CONVERGENCE_RTOL:
            return fit_b, fit_c, passes
    raise IdentificationError(
        f"steps B and C did not converge in {max_passes} passes (last change {change:.2g})"
    )


@jax.jit
def _bending_rows(
    params: HsaParams, theta: dict[str, Array], xi_d: Array, phi: Array, G: Array
) -> tuple[Array, Array]:
    """Jacobian (N, 3, 7) along [BENDING_KEYS, sigma_a_eq,1, sigma_a_eq,2] at zero, and the value
    there (N, 3)."""

    def r(z: Array, x: Array, p: Array, g: Array) -> Array:
        th = {**theta, **dict(zip(BENDING_KEYS, z[:5]))}
        return g + elastic_actuation_force(params, th, z[5:], x, p)

    z0 = jnp.zeros(7)
    jac = jax.vmap(jax.jacfwd(r), in_axes=(None, 0, 0, 0))(z0, xi_d, phi, G)
    val = jax.vmap(r, in_axes=(None, 0, 0, 0))(z0, xi_d, phi, G)
    return jac, val


def step_e(
    params: HsaParams, samples: Samples, theta: dict[str, float]
) -> tuple[LinearFit, dict[int, np.ndarray]]:
    """Step E with D: bending and shear constants plus per-side rest strains of each bending record,
    all three rows."""
    records = np.unique(samples.record)
    col = _record_columns(samples, records)
    xi_d = dynamic_strains(params, samples.xi)
    G = gravity_at(params, samples.xi, samples.payload)
    jac, val = (
        np.asarray(a)
        for a in _bending_rows(params, _theta_of(theta), xi_d, jnp.asarray(samples.phi), G)
    )
    n = len(col)
    A = np.zeros((n, 3, 5 + 2 * len(records)))
    A[:, :, :5] = jac[:, :, :5]
    for k in range(n):
        A[k, :, 5 + 2 * col[k] : 7 + 2 * col[k]] = jac[k, :, 5:]
    names = (
        *BENDING_KEYS,
        *[f"sigma_a_eq{j}[{samples.records[r]}]" for r in records for j in (1, 2)],
    )
    fit = solve_linear(A.reshape(3 * n, -1), -val.reshape(-1), names, list(ROWS) * n)
    return fit, {int(r): fit.estimate[5 + 2 * i : 7 + 2 * i].copy() for i, r in enumerate(records)}


def min_stiffness_eigenvalue(params: HsaParams, theta: dict[str, float], n_grid: int = 11) -> float:
    """Smallest eigenvalue of d(K - alpha)/dxi over a grid of phi in [0, phi_max]^2 (must be > 0, §7
    item 8)."""
    grid = np.linspace(0.0, 1.0, n_grid)
    phis = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2) * np.asarray(
        params.phi_max
    )

    def stiffness(phi: Array) -> Array:
        return jax.jacfwd(elastic_actuation_force, argnums=3)(
            params, theta, jnp.asarray(params.sigma_a_eq), jnp.zeros(3), phi
        )

    mats = np.asarray(jax.jit(jax.vmap(stiffness))(jnp.asarray(phis)))
    return float(np.min(np.linalg.eigvalsh(0.5 * (mats + np.swapaxes(mats, 1, 2)))))


@functools.partial(jax.jit, static_argnames=("n_records",))
def _joint_residual(
    params: HsaParams, z: Array, xi_d: Array, phi: Array, G: Array, record: Array, n_records: int
) -> Array:
    """Stacked equilibrium residuals (N * 3,) for z = [ELASTIC_KEYS, sigma_a_eq,1/2 of every
    record]."""
    theta = dict(zip(ELASTIC_KEYS, z[: len(ELASTIC_KEYS)]))
    sigma = z[len(ELASTIC_KEYS) :].reshape(n_records, 2)[record]
    r = jax.vmap(lambda x, p, g, s: g + elastic_actuation_force(params, theta, s, x, p))(
        xi_d, phi, G, sigma
    )
    return r.reshape(-1)


_joint_jacobian = jax.jit(jax.jacfwd(_joint_residual, argnums=1), static_argnames=("n_records",))


def refine(
    params: HsaParams,
    samples: Samples,
    theta: dict[str, float],
    sigma: dict[int, np.ndarray],
    max_iter: int = 20,
) -> LinearFit:
    """Step F: all constants and every record's per-side rest strains jointly (Gauss-Newton from the
    sequential estimates, all three rows of every sample). The covariance then includes what the
    sequential steps pass on."""
    n_rec = len(samples.records)
    xi_d = dynamic_strains(params, samples.xi)
    G = gravity_at(params, samples.xi, samples.payload)
    phi, record = jnp.asarray(samples.phi), jnp.asarray(samples.record)
    z = np.concatenate(
        [[theta[key] for key in ELASTIC_KEYS], np.concatenate([sigma[r] for r in range(n_rec)])]
    )
    names = (*ELASTIC_KEYS, *[f"sigma_a_eq{j}[{name}]" for name in samples.records for j in (1, 2)])
    types = list(ROWS) * len(samples.xi)
    for _ in range(max_iter):
        r = np.asarray(_joint_residual(params, jnp.asarray(z), xi_d, phi, G, record, n_rec))
        J = np.asarray(_joint_jacobian(params, jnp.asarray(z), xi_d, phi, G, record, n_rec))
        fit = solve_linear(J, J @ z - r, names, types)
        step, z = fit.estimate - z, fit.estimate
        if np.all(np.abs(step) <= 1e-10 * np.abs(z)):
            return fit
    raise IdentificationError(
        f"joint refinement did not converge in {max_iter} Gauss-Newton iterations"
    )


@dataclasses.dataclass(frozen=True)
class IdentificationResult:
    """Identified constants (per physical rod), the fit of every step, record rest strains and
    checks."""

    values: dict[str, float]
    std: dict[str, float]
    ci: dict[str, tuple[float, float]]
    fits: dict[str, LinearFit]
    sigma_a_eq: dict[str, np.ndarray]
    bc_passes: int
    min_stiffness_eig: float
    n_samples: int


def identify(params: HsaParams, samples: Samples) -> IdentificationResult:
    """Steps A, B <-> C, E (+D), then the joint refinement F; `params` supplies geometry, masses and
    the kappa rule.

    Values, standard errors and intervals are those of F; the sequential fits are kept in `fits` for
    the report.
    """
    elong = np.array([samples.roles[r] == "elongation" for r in samples.record])
    rest = np.all(np.abs(samples.phi) < 1e-3, axis=1)
    if not np.any(elong & rest):
        raise IdentificationError(
            "step A needs phi = 0 settled samples of an elongation record (with payloads)"
        )
    fit_a, sigma_elong = step_a(params, samples.select(elong & rest))
    theta = {"S_a_hat": fit_a.value("S_a_hat")}
    elong_samples = samples.select(elong & np.isin(samples.record, list(sigma_elong)))
    fit_b, fit_c, passes = steps_b_c(params, elong_samples, theta, sigma_elong)
    theta.update(C_eps=fit_b.value("C_eps"), C_S_a=fit_c.value("C_S_a"))
    bending = np.array([samples.roles[r] == "bending" for r in samples.record])
    if not np.any(bending):
        raise IdentificationError("step E needs settled samples of a bending record")
    fit_e, sigma_bend = step_e(params, samples.select(bending), _theta_of(theta))
    theta.update({key: fit_e.value(key) for key in BENDING_KEYS})
    missing = sorted(set(range(len(samples.records))) - set(sigma_elong) - set(sigma_bend))
    if missing:
        raise IdentificationError(
            f"no rest strain for record(s) {[samples.records[r] for r in missing]}: an "
            "elongation record needs phi = 0 holds"
        )
    sigma0 = {**{r: np.array([s, s]) for r, s in sigma_elong.items()}, **sigma_bend}
    fit_f = refine(params, samples, _theta_of(theta), sigma0)
    fits = {"A": fit_a, "B": fit_b, "C": fit_c, "E": fit_e, "F": fit_f}
    n_keys = len(ELASTIC_KEYS)
    values = {key: float(fit_f.estimate[i]) for i, key in enumerate(ELASTIC_KEYS)}
    return IdentificationResult(
        values=values,
        std={key: float(fit_f.std[i]) for i, key in enumerate(ELASTIC_KEYS)},
        ci={
            key: (float(fit_f.ci_low[i]), float(fit_f.ci_high[i]))
            for i, key in enumerate(ELASTIC_KEYS)
        },
        fits=fits,
        sigma_a_eq={
            name: fit_f.estimate[n_keys + 2 * r : n_keys + 2 * r + 2].copy()
            for r, name in enumerate(samples.records)
        },
        bc_passes=passes,
        min_stiffness_eig=min_stiffness_eigenvalue(params, values),
        n_samples=len(samples.xi),
    )


# --------------------------------------------------------------------------------------------------
# parameter file and report


_FLOW_LIST = r"^({key}:\s*)\[[^\]\n]*\]"


def update_parameter_text(text: str, updates: dict[str, Sequence[float]]) -> str:
    """Replace the flow-style values of `updates` in a parameter YAML text, keeping every comment
    and other line.

    Keys missing from the text, or not written as a one-line list, make the whole file be re-dumped
    without comments.
    """
    out = text
    for key, values in updates.items():
        new = "[" + ", ".join(repr(float(v)) for v in values) + "]"
        out, count = re.subn(
            _FLOW_LIST.format(key=re.escape(key)), lambda m: m.group(1) + new, out, flags=re.M
        )
        if count != 1:
            raw = yaml.safe_load(text)
            raw.update({k: [float(v) for v in vals] for k, vals in updates.items()})
            return yaml.safe_dump(raw, sort_keys=False)
    return out


def write_parameter_file(
    base: Path, out: Path, updates: dict[str, Sequence[float]], header: str = ""
) -> Path:
    """Write `base` with `updates` applied to `out` (atomically: temporary file, then rename);
    header lines prefixed."""
    text = update_parameter_text(Path(base).read_text(), updates)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text)
    tmp.replace(out)
    return out


def parameter_updates(result: IdentificationResult) -> dict[str, list[float]]:
    """The identified constants as YAML entries (the same per-physical-rod value for both virtual
    rods)."""
    return {key: [value, value] for key, value in result.values.items()}


def format_report(
    result: IdentificationResult, reference: dict[str, float] | None = None, label: str = "base set"
) -> str:
    """Plain-text fit report: estimates with standard errors and 95 % intervals (compared with
    `reference`, named `label`), per-step rows, condition numbers and residuals, rest strains per
    record and the stiffness check."""
    ref_head = f"  {label:>11s}    rel. diff" if reference else ""
    lines = [f"{'parameter':10s} {'estimate':>14s} {'std':>11s} {'95% CI':>29s}{ref_head}"]
    for key in ELASTIC_KEYS:
        value, (lo, hi) = result.values[key], result.ci[key]
        line = f"{key:10s} {value:14.8g} {result.std[key]:11.3g}   [{lo:12.6g}, {hi:12.6g}]"
        if reference:
            ref = reference[key]
            line += (
                f"  {ref:11.6g}  {(value - ref) / abs(ref):+9.2e}"
                if ref != 0.0
                else f"  {ref:11.6g}"
            )
        lines.append(line)
    lines.append("")
    for name, fit in result.fits.items():
        rms = ", ".join(f"{k} {v:.3g}" for k, v in fit.residual_rms.items())
        lines.append(
            f"step {name}: {fit.n_rows} rows, {len(fit.names)} unknowns, scaled condition "
            f"{fit.condition_number:.3g}, residual RMS per row type: {rms}"
        )
    lines.append(f"B <-> C passes to {CONVERGENCE_RTOL:.0e} relative change: {result.bc_passes}")
    lines.append(
        "rest strains per record (sigma_a_eq,1, sigma_a_eq,2): "
        + "; ".join(f"{name} {s[0]:.6f}, {s[1]:.6f}" for name, s in result.sigma_a_eq.items())
    )
    verdict = (
        "positive definite"
        if result.min_stiffness_eig > 0.0
        else "NOT positive definite: use bounded LS"
    )
    lines.append(
        "generalized stiffness over [0, phi_max]^2: smallest eigenvalue "
        f"{result.min_stiffness_eig:.4g} "
        f"({verdict})"
    )
    lines.append(f"settled samples: {result.n_samples}")
    return "\n".join(lines)


def plot_fit(result: IdentificationResult, path: Path) -> Path:
    """Figure: measured target b against the fitted A Pi per step and row type (points on the
    diagonal = perfect)."""
    from hsa_core.analysis.plotting import save, subplots  # matplotlib only where a figure is drawn

    fig, axes = subplots(1, len(result.fits), figsize=(4.2 * len(result.fits), 4.0))
    for ax, (name, fit) in zip(np.atleast_1d(axes), result.fits.items()):
        predicted = fit.b - fit.residuals
        for kind in np.unique(fit.row_types):
            sel = fit.row_types == kind
            ax.plot(fit.b[sel], predicted[sel], "o", ms=4, label=kind)
        lim = [float(np.min(fit.b)), float(np.max(fit.b))]
        ax.plot(lim, lim, "k--", lw=0.8)
        ax.set_title(
            f"step {name}: {', '.join(fit.names[:3])}{'...' if len(fit.names) > 3 else ''}",
            fontsize=8,
        )
        ax.set_xlabel("target b (gravity and known terms)")
        ax.set_ylabel("fitted A Pi")
        ax.legend(fontsize=7)
    return save(fig, path)

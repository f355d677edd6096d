"""Calibration of the axial rest strains sigma_a_eq of the two virtual rods at rest
(planning_and_control.md §6.5).

With phi = 0 and the robot hanging still, every measured configuration satisfies G(xi_k) + K(xi_k;
sigma_a_eq) = 0. K is affine in sigma_a_eq: its sigma_a_eq part is -[roff_i S_a,i, 0, S_a,i]^T
sigma_a_eq,i, so

    [[roff_1 S_a,1, roff_2 S_a,2], [S_a,1, S_a,2]] sigma_a_eq = (G + K)(xi_k; sigma_ref) + B
    sigma_ref

per sample (kappa and sigma_ax rows; the sigma_sh row has no sigma_a_eq in it and is dropped,
identification.md §4.2). The samples are stacked and solved by
:func:`hsa_core.sysid.identification.solve_linear` (row-type weights, one-sigma uncertainty,
residual RMS). The strains xi are those of the poses, so the result does not depend on the rest
strains the incoming q were computed with. :func:`rest_problem` refuses windows in which the robot
moves or phi != 0.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from numpy.typing import ArrayLike

from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import HsaParams
from hsa_core.sysid.identification import LinearFit, solve_linear

MIN_SAMPLES = 5
DEFAULT_SAMPLES = 20
"""Samples per calibration: the last 20 mocap samples, as the original (§6.5)."""
PHI_TOL = 0.01
"""Largest |phi| [rad] that counts as untwisted (about 6 encoder ticks)."""
MAX_POSITION_SPREAD = 1e-3
MAX_ANGLE_SPREAD = 0.015
"""Largest peak-to-peak EE position [m] and angle [rad] in the window at rest (mocap noise ~0.1 mm,
1 mrad sigma)."""
MAX_SPEED = 2e-3
"""Largest EE drift speed [m/s] (least-squares slope over the window) at rest."""


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Estimated rest strains of virtual rods 1 and 2 with one-sigma uncertainty, residual RMS and
    the fit."""

    sigma_a_eq: np.ndarray
    sigma_a_eq_std: np.ndarray
    residual_rms: float
    samples_used: int
    fit: LinearFit


def rest_problem(
    t: ArrayLike,
    chiee: ArrayLike,
    phi: ArrayLike,
    phi_tol: float = PHI_TOL,
    max_spread: float = MAX_POSITION_SPREAD,
    max_angle_spread: float = MAX_ANGLE_SPREAD,
    max_speed: float = MAX_SPEED,
    min_samples: int = MIN_SAMPLES,
) -> str | None:
    """Why the window (stamps t (N,), poses chiee (N, 3), phi (M, 2)) is not a rest at phi = 0; None
    if it is."""
    t, chiee, phi = (
        np.asarray(t, float),
        np.asarray(chiee, float),
        np.asarray(phi, float).reshape(-1, 2),
    )
    if len(t) < min_samples:
        return f"not enough samples ({len(t)} < {min_samples})"
    if len(phi) == 0:
        return "no actuation (phi) received"
    if not (np.all(np.isfinite(chiee)) and np.all(np.isfinite(phi))):
        return "non-finite samples in the window"
    if np.max(np.abs(phi)) > phi_tol:
        return f"phi != 0 (max |phi| {np.max(np.abs(phi)):.4f} rad > {phi_tol} rad)"
    spread = np.ptp(chiee, axis=0)
    if max(spread[0], spread[1]) > max_spread:
        return (
            f"robot moving (EE position spread {max(spread[:2]) * 1e3:.2f} mm > "
            f"{max_spread * 1e3:.2f} mm)"
        )
    if spread[2] > max_angle_spread:
        return f"robot moving (EE angle spread {spread[2]:.4f} rad > {max_angle_spread} rad)"
    if np.ptp(t) > 0.0:
        slope = np.polyfit(t - t[0], chiee[:, :2], 1)[0]
        speed = float(np.linalg.norm(slope))
        if speed > max_speed:
            return f"robot drifting (EE speed {speed * 1e3:.2f} mm/s > {max_speed * 1e3:.2f} mm/s)"
    return None


@jax.jit
def _rows(params: HsaParams, chiee: Array) -> tuple[Array, Array]:
    """Regressor (N, 3, 2) and target (N, 3) of the rest equations for a batch of poses."""
    zero = jnp.zeros(2)

    def one(pose: Array) -> tuple[Array, Array]:
        # relative to the reference rest strains of params
        q = kinematics.inverse_kinematics(params, pose)

        def residual(sigma: Array) -> Array:
            # q relative to sigma instead of params.sigma_a_eq: the same strains xi, another split
            # into xi_eq + q
            p = dataclasses.replace(params, sigma_a_eq=sigma)
            return dynamics.static_residual(p, q + params.xi_eq - p.xi_eq, zero)

        B = -jax.jacfwd(residual)(params.sigma_a_eq)  # affine in sigma: exact
        return B, residual(params.sigma_a_eq) + B @ params.sigma_a_eq

    return jax.vmap(one)(chiee)


def calibrate(params: HsaParams, chiee: ArrayLike) -> Calibration:
    """Least-squares sigma_a_eq (virtual rods 1, 2) from EE poses at rest with phi = 0 (check with
    rest_problem)."""
    chiee = np.asarray(chiee, dtype=float).reshape(-1, 3)
    B, b = (np.asarray(a) for a in _rows(params, jnp.asarray(chiee)))
    rows = [0, 2]  # kappa and sigma_ax; the sigma_sh row does not contain sigma_a_eq
    A = B[:, rows, :].reshape(-1, 2)
    target = b[:, rows].reshape(-1)
    fit = solve_linear(
        A, target, ("sigma_a_eq1", "sigma_a_eq2"), ["kappa", "sigma_ax"] * len(chiee)
    )
    return Calibration(
        fit.estimate.copy(),
        fit.std.copy(),
        float(np.sqrt(np.mean(fit.residuals**2))),
        len(chiee),
        fit,
    )

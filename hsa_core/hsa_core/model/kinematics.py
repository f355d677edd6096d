"""Kinematics of the planar HSA robot: one constant-strain backbone, two virtual rods, rigid
platform (model.md §6).

All positions are written with the entire functions S and C of model.md §8.2, so they are exact and
smooth at kappa = 0. Inputs q are relative to the rest strains: xi = xi_eq + q. With
`params.kappa_rule == "exp2023_shift"` the forward kinematics (backbone, rods, EE, J_ee) use
kappa_kin = kappa + sign(kappa) 1e-6 (model.md §8.4(1)); the inverse kinematics, rod strains and
twist elongation are always exact.
"""

import jax
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from hsa_core.model.params import HsaParams
from hsa_core.model.smooth import C, S, c

KAPPA_SHIFT_KIN = 1e-6
"""exp2023 curvature shift of the kinematics [1/m] (model.md §8.1)."""


def strains(params: HsaParams, q: ArrayLike) -> Array:
    """Backbone strains xi = xi_eq + q; every model term is a function of xi, not of q (model.md
    §9.3)."""
    return params.xi_eq + jnp.asarray(q, dtype=jnp.float64)


def apply_kappa_rule(params: HsaParams, xi: Array, shift: float) -> Array:
    """Return xi with kappa moved by sign(kappa) * shift (sign(0) = +1) in "exp2023_shift" mode,
    else xi unchanged."""
    if params.kappa_rule == "exact":
        return xi
    sign = jnp.where(xi[0] >= 0.0, 1.0, -1.0)
    return xi.at[0].add(sign * shift)


def rotate(theta: ArrayLike, v: ArrayLike) -> Array:
    """R(theta) v for planar vectors v (..., 2), broadcasting theta over the leading axes."""
    v = jnp.asarray(v)
    cos, sin = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack(
        [cos * v[..., 0] - sin * v[..., 1], sin * v[..., 0] + cos * v[..., 1]], axis=-1
    )


def points_in_base(params: HsaParams, xi: Array, s: ArrayLike, d: ArrayLike) -> Array:
    """Positions p(s) + R(kappa s) d of points rigidly attached to the backbone at arc length s with
    local offset d."""
    kappa, sigma_sh, sigma_ax = xi[0], xi[1], xi[2]
    s = jnp.asarray(s, dtype=jnp.float64)
    x = kappa * s
    S_x, xC_x = S(x), x * C(x)
    backbone = jnp.stack(
        [
            s * (sigma_sh * S_x - sigma_ax * xC_x),
            params.l_pc + s * (sigma_sh * xC_x + sigma_ax * S_x),
        ],
        axis=-1,
    )
    return backbone + rotate(x, d)


def end_effector_offset(params: HsaParams) -> Array:
    """EE position in the backbone-tip frame: l_dc + h_p up to the platform surface, plus chiee_off
    (model.md §6.2)."""
    return jnp.array([0.0, params.l_dc + params.platform_size[1]]) + params.chiee_off[:2]


def backbone_pose(params: HsaParams, q: ArrayLike, s: ArrayLike) -> Array:
    """Backbone pose [p_x, p_y, theta] at arc length s in {0} (model.md §6.1); s may be an array
    (..., 3)."""
    xi = apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_KIN)
    s = jnp.asarray(s, dtype=jnp.float64)
    p = points_in_base(params, xi, s, jnp.zeros(s.shape + (2,)))
    return jnp.concatenate([p, (xi[0] * s)[..., None]], axis=-1)


def rod_positions(params: HsaParams, q: ArrayLike, s: ArrayLike) -> Array:
    """Centreline positions of virtual rods 1 and 2 at arc length s, shape (..., 2 rods, 2)
    (model.md §6.2)."""
    xi = apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_KIN)
    s = jnp.asarray(s, dtype=jnp.float64)[..., None]
    d = jnp.stack([params.roff, jnp.zeros(2)], axis=-1)
    return points_in_base(params, xi, s, d)


def platform_pose(params: HsaParams, q: ArrayLike) -> Array:
    """Pose [x, y, theta] of the platform CoG, p_c = p(l) + R(kappa l) [0, y_c] (model.md §6.2)."""
    xi = apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_KIN)
    p_c = points_in_base(params, xi, params.l, jnp.stack([jnp.zeros(()), params.y_c]))
    return jnp.concatenate([p_c, (xi[0] * params.l)[None]])


def end_effector_pose(params: HsaParams, q: ArrayLike) -> Array:
    """End-effector pose chiee = [x, y, theta] in {0} (model.md §6.2)."""
    xi = apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_KIN)
    p_ee = points_in_base(params, xi, params.l, end_effector_offset(params))
    return jnp.concatenate([p_ee, (xi[0] * params.l + params.chiee_off[2])[None]])


def end_effector_jacobian(params: HsaParams, q: ArrayLike) -> Array:
    """J_ee = d chiee / d q (3x3) by forward-mode autodiff of the smooth forward kinematics."""
    return jax.jacfwd(end_effector_pose, argnums=1)(params, jnp.asarray(q, dtype=jnp.float64))


def inverse_kinematics(params: HsaParams, chiee: ArrayLike) -> Array:
    """Configuration q from an EE pose with the exact, bias-free closed form of model.md §6.3 (valid
    for |theta| < 2 pi)."""
    chiee = jnp.asarray(chiee, dtype=jnp.float64)
    l = params.l
    theta_b = chiee[2] - params.chiee_off[2]
    u = chiee[:2] - rotate(theta_b, end_effector_offset(params)) - jnp.array([0.0, params.l_pc])
    c_b = c(theta_b)
    xi = jnp.stack(
        [
            theta_b / l,
            (theta_b * u[1] / 2.0 + c_b * u[0]) / l,
            (-theta_b * u[0] / 2.0 + c_b * u[1]) / l,
        ]
    )
    return xi - params.xi_eq


def rod_strains(params: HsaParams, q: ArrayLike) -> Array:
    """Strains beta_i = J_beta,i xi = [kappa, sigma_sh, sigma_ax + roff_i kappa] of both rods, shape
    (2, 3) (§6.4)."""
    kappa, sigma_sh, sigma_ax = strains(params, q)
    return jnp.stack(
        [jnp.full(2, kappa), jnp.full(2, sigma_sh), sigma_ax + params.roff * kappa], axis=-1
    )


def twist_elongation(params: HsaParams, phi: ArrayLike) -> Array:
    """Axial rest-strain elongation eps_i = C_eps,i h_i phi_i / l caused by twisting rod i (model.md
    §6.4)."""
    return params.C_eps * params.h * jnp.asarray(phi, dtype=jnp.float64) / params.l

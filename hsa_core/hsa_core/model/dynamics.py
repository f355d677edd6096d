"""Dynamics of the planar HSA robot: M q_ddot + C q_dot + G + K + D q_dot = alpha (model.md §7).

Inertia and gravity are sums over mass points: 8 Gauss-Legendre nodes on each virtual rod (model.md
§9.1), the platform CoG and the payload, vectorised as 2 layers over the 9 arc positions they share
(nodes + tip). The point Jacobians are written in closed form with E(x) = S(x) + i x C(x) and its
first two derivatives (smooth.arc_terms, exact and smooth at kappa = 0, §8.2). One contraction of
them gives M (§7.2), C (the Christoffel-symbol matrix of §7.3, evaluated as sum m J^T J_dot) and G =
dU_g/dxi (§7.4); the forward dynamics takes M, C q_dot and G from the same sums written elementwise,
the two layers merged at each arc position and the sums taken in one XLA reduction
(:func:`_inertial_forces`). K, D, alpha and A are closed forms (§7.5-7.7) and the collocated map
follows planning_and_control.md §3.2. Parameter-only terms are folded to constants when the
parameters are closed over. The compiled graph is a few fused XLA kernels, which keeps the compile
time (~0.3 s) and the per-evaluation cost (~0.5 us inside a simulation loop, ~0.19 us per run
batched 64 to a CPU core) low.

With `params.kappa_rule == "exp2023_shift"`, M, C, G, K, alpha, A and q_ddot are evaluated at
kappa_dyn = kappa + sign(kappa) 0.01 (model.md §8.4(1)); the collocated map is always exact.
"""

from types import ModuleType
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from hsa_core.model.kinematics import apply_kappa_rule, points_in_base, strains
from hsa_core.model.params import HsaParams
from hsa_core.model.smooth import arc_functions, arc_terms

KAPPA_SHIFT_DYN = 1e-2
"""exp2023 curvature shift of the dynamics [1/m] (model.md §8.1)."""

N_GAUSS = 8
"""Gauss-Legendre nodes per rod; 8 nodes reproduce the symbolic integrals to <= 1e-14 for |kappa| <=
50 1/m (§9.1)."""

_GL_X, _GL_W = np.polynomial.legendre.leggauss(N_GAUSS)


class DynamicalMatrices(NamedTuple):
    """All terms of the equation of motion at one state (model.md §7.8 for units)."""

    M: Array
    C: Array
    G: Array
    K: Array
    D: Array
    alpha: Array
    A: Array


class MassPoints(NamedTuple):
    """Point masses discretising the moving bodies, as 2 layers over the same 9 arc positions.

    s (9,): the 8 Gauss-Legendre nodes and the tip s = l. Layer 0 holds rod 1 at the nodes and the
    platform CoG at the tip, layer 1 rod 2 and the payload. m (2, 9) are masses, d (2, 9, 2) offsets
    in the local frame at s, and inertia_kk is the rotational inertia of rods and platform about the
    kappa direction (J_o = [s, 0, 0]).
    """

    s: Array
    m: Array
    d: Array
    inertia_kk: Array


def mass_points(params: HsaParams, xp: ModuleType = jnp) -> MassPoints:
    """Quadrature points of both rods, platform CoG and payload; computed once per parameter set
    (model.md §7.2).

    `xp` is the array namespace: jax.numpy (traced parameters) or numpy (concrete parameters folded
    to constants).
    """
    l = params.l
    w_nodes = l * _GL_W / 2.0
    rod_density = params.rho_r * params.area  # linear density of each virtual rod [kg/m]
    theta_off, cog = params.chiee_off[2], params.CoG_pl
    # platform CoG (model.md §6.2) and payload CoG (EE offset plus R(theta_off) CoG_pl)
    tip_offsets = xp.stack(
        [
            xp.stack([xp.zeros(()), params.y_c]),
            xp.stack(
                [
                    params.chiee_off[0] + xp.cos(theta_off) * cog[0] - xp.sin(theta_off) * cog[1],
                    params.l_dc
                    + params.platform_size[1]
                    + params.chiee_off[1]
                    + xp.sin(theta_off) * cog[0]
                    + xp.cos(theta_off) * cog[1],
                ]
            ),
        ]
    )
    rod_offsets = xp.stack(
        [xp.broadcast_to(params.roff[:, None], (2, N_GAUSS)), xp.zeros((2, N_GAUSS))], axis=-1
    )
    return MassPoints(
        s=xp.concatenate([l * (_GL_X + 1.0) / 2.0, l[None]]),
        m=xp.concatenate(
            [rod_density[:, None] * w_nodes[None, :], xp.stack([params.m_p, params.m_pl])[:, None]],
            axis=1,
        ),
        d=xp.concatenate([rod_offsets, tip_offsets[:, None, :]], axis=1),
        inertia_kk=(params.rho_r * params.second_moment).sum() * l**3 / 3.0 + params.I_p * l**2,
    )


def _cmul(a: Array, b: Array) -> Array:
    """Complex product of planar vectors stored as (re, im) along axis 0."""
    return jnp.stack([a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]])


def _rot90(a: Array) -> Array:
    """i * a for planar vectors stored as (re, im) along axis 0."""
    return jnp.stack([-a[1], a[0]])


def _point_jacobians(mp: MassPoints, xi: Array, xi_dot: Array) -> tuple[Array, Array]:
    """Jacobians J = dp/dxi and their time derivatives J_dot of all mass points, each (3 columns,
    re/im, 2, 9).

    In complex notation a point at arc s with local offset d sits at p = i l_pc + w F(s) + e^{i
    kappa s} d, with w = sigma_sh + i sigma_ax and F(s) = s E(kappa s), E = S + i x C (model.md
    §6.1-6.2, §8.2). Hence J_sh = F, J_ax = i F, J_kappa = w F_kappa + i s e^{i kappa s} d, with
    F_kappa = s^2 E'(kappa s), F_kappa,kappa = s^3 E''.
    """
    s = mp.s
    w, w_dot, kappa_dot = xi[1:, None, None], xi_dot[1:, None, None], xi_dot[0]
    # one kernel for all arc functions at the 9 arc positions (shared by both layers)
    f = jax.lax.optimization_barrier(arc_functions(xi[0] * s))
    E, E1, E2, e_ix = f[0::3][:2], f[1::3][:2], f[2::3][:2], f[6:8]
    F, F_k, F_kk = (s * E)[:, None], (s * s * E1)[:, None], (s**3 * E2)[:, None]
    e_d = _cmul(e_ix[:, None], jnp.moveaxis(mp.d, -1, 0))
    J = jnp.stack(
        [
            _cmul(w, F_k) + s * _rot90(e_d),
            jnp.broadcast_to(F, e_d.shape),
            jnp.broadcast_to(_rot90(F), e_d.shape),
        ]
    )
    dJ_kappa_dkappa = _cmul(w, F_kk) - s * s * e_d
    J_dot = jnp.stack(
        [
            _cmul(w_dot, F_k) + kappa_dot * dJ_kappa_dkappa,
            jnp.broadcast_to(kappa_dot * F_k, e_d.shape),
            jnp.broadcast_to(kappa_dot * _rot90(F_k), e_d.shape),
        ]
    )
    return J, J_dot


def _inertial_terms(
    params: HsaParams, mp: MassPoints, xi: Array, xi_dot: Array
) -> tuple[Array, Array, Array]:
    """M = sum_k m_k J_k^T J_k (+ rotation), C = sum_k m_k J_k^T J_dot_k and G = -sum_k m_k J_k^T g.

    C is exactly the Christoffel-symbol matrix of model.md §7.3 for this M, because Gamma_ijk =
    sum_k m_k <J_i, d^2 p_k / dxi_j dxi_k> for a sum of point masses plus a constant rotational
    Jacobian. G is the gradient of U_g = -sum_k m_k g^T p_k (§7.4).
    """
    J, J_dot = _point_jacobians(mp, xi, xi_dot)
    # one kernel for all Jacobian entries
    JJ = jax.lax.optimization_barrier(jnp.concatenate([J, J_dot]))
    J, J_dot = JJ[:3], JJ[3:]
    M = jnp.sum(J[:, None] * J[None] * mp.m, axis=(2, 3, 4)) + jnp.zeros((3, 3)).at[0, 0].set(
        mp.inertia_kk
    )
    C = jnp.sum(J[:, None] * J_dot[None] * mp.m, axis=(2, 3, 4))
    G = -jnp.sum(J * params.g[:, None, None] * mp.m, axis=(1, 2, 3))
    return M, C, G


def _times(a: tuple[Array, Array], b: tuple[Array, Array]) -> tuple[Array, Array]:
    """Complex product a b of planar vectors stored as (re, im) pairs."""
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _dot(a: tuple[Array, Array], b: tuple[Array, Array]) -> Array:
    """Re(conj(a) b) of planar vectors stored as (re, im) pairs."""
    return a[0] * b[0] + a[1] * b[1]


def _cross(a: tuple[Array, Array], b: tuple[Array, Array]) -> Array:
    """Im(conj(a) b) of planar vectors stored as (re, im) pairs."""
    return a[0] * b[1] - a[1] * b[0]


def _gravity_of(params: HsaParams, mp: MassPoints, xi: Array) -> Array:
    """G_j = -sum_k m_k <J_j, g> (:func:`_inertial_terms`' G, point by point in complex notation):
    J_sh = F, J_ax = i F (so <J_ax, g> = cross(F, g)) and J_k = w F_k + i s e^{i kappa s} d
    (:func:`_point_jacobians`)."""
    s = mp.s
    # computed once, not inside every consumer kernel
    f = jax.lax.optimization_barrier(arc_functions(xi[0] * s))
    F, F_k = (s * f[0], s * f[3]), (s * s * f[1], s * s * f[4])
    e_d = _times((f[6], f[7]), (mp.d[:, :, 0], mp.d[:, :, 1]))  # e^{i kappa s} d, per layer
    wF_k = _times((xi[1], xi[2]), F_k)
    J_k = (wF_k[0] - s * e_d[1], wF_k[1] + s * e_d[0])
    g = (params.g[0], params.g[1])
    return -jnp.stack(
        [jnp.sum(mp.m * term, axis=(0, 1)) for term in (_dot(J_k, g), _dot(F, g), _cross(F, g))]
    )


def _sums(terms: tuple[Array, ...]) -> tuple[Array, ...]:
    """The sum of each term over the arc positions, as one variadic XLA reduction (one kernel that
    computes the shared factors once; separate sums are separate kernels, each recomputing its
    factors: ~2x slower on the CPU)."""
    return jax.lax.reduce(
        terms, (0.0,) * len(terms), lambda a, b: tuple(x + y for x, y in zip(a, b)), (0,)
    )


def _inertial_forces(
    params: HsaParams, mp: MassPoints, xi: Array, xi_dot: Array
) -> tuple[Array, Array, Array]:
    """M, C q_dot and G of :func:`_inertial_terms`, as weighted sums over the 9 arc positions (no
    Jacobian arrays).

    With dot(a, b) = Re(conj(a) b) and cross(a, b) = Im(conj(a) b) for planar vectors in complex
    notation and the columns J_sh = F, J_ax = i F (the same at both layers), M = [[|J_k|^2 + I_kk,
    dot(J_k, F), cross(F, J_k)], [., |F|^2, 0], [., 0, |F|^2]], (C q_dot)_j = <J_j, v> with v =
    J_dot q_dot = kappa_dot (2 w_dot F_k + kappa_dot dJ_k/dkappa), G_j = -<J_j, g>, each summed over
    the points with their masses. The two layers share F, F_k and F_kk and differ in J_k = w F_k + i
    s e^{i kappa s} d and dJ_k/dkappa = w F_kk - s^2 e^{i kappa s} d only through the offset d,
    which enters linearly (|e^{i kappa s} d|^2 = |d|^2): so each sum over a position's two points is
    one term in the position's mass m_0 + m_1, its first moment m_0 d_0 + m_1 d_1 and its second
    moment m_0 |d_0|^2 + m_1 |d_1|^2. The ten sums are one XLA kernel (:func:`_sums`); per
    evaluation ~3x faster than the point-by-point sums on the CPU, batched or not
    (benchmarks/results/closed_loop.json); tests/core/test_dynamics.py checks the result against
    :func:`_inertial_terms`.
    """
    s, (m0, m1), (d0, d1) = mp.s, mp.m, mp.d
    S0, S1, S2, B0, B1, B2, cos, sin = arc_terms(xi[0] * s)
    mass = m0 + m1
    # e^{i kappa s} sum m d
    moment = _times((cos, sin), (m0 * d0[:, 0] + m1 * d1[:, 0], m0 * d0[:, 1] + m1 * d1[:, 1]))
    second_moment = m0 * (d0[:, 0] ** 2 + d0[:, 1] ** 2) + m1 * (d1[:, 0] ** 2 + d1[:, 1] ** 2)
    F, F_k, F_kk = (s * S0, s * B0), (s * s * S1, s * s * B1), (s**3 * S2, s**3 * B2)
    w, w_dot, kappa_dot = (xi[1], xi[2]), (xi_dot[1], xi_dot[2]), xi_dot[0]
    wF_k, wdF_k, wF_kk = _times(w, F_k), _times(w_dot, F_k), _times(w, F_kk)
    i_moment = (-s * moment[1], s * moment[0])  # i s e^{i kappa s} sum m d
    J_k = (mass * wF_k[0] + i_moment[0], mass * wF_k[1] + i_moment[1])  # sum m J_k
    # v without the offset term
    common = tuple(kappa_dot * (2.0 * a + kappa_dot * b) for a, b in zip(wdF_k, wF_kk))
    offset = kappa_dot * kappa_dot * s * s
    v = (mass * common[0] - offset * moment[0], mass * common[1] - offset * moment[1])  # sum m v
    mF, g = (mass * F[0], mass * F[1]), (params.g[0], params.g[1])
    m_kk, m_ks, m_ka, m_ff, c_k, c_s, c_a, g_k, g_s, g_a = _sums(
        (
            mass * _dot(wF_k, wF_k) + 2.0 * _dot(wF_k, i_moment) + s * s * second_moment,
            _dot(J_k, F),
            _cross(F, J_k),
            _dot(mF, F),
            _dot(J_k, common) - offset * _dot(wF_k, moment),
            _dot(F, v),
            _cross(F, v),
            _dot(J_k, g),
            _dot(mF, g),
            _cross(mF, g),
        )
    )
    m_kk = m_kk + mp.inertia_kk
    zero = jnp.zeros_like(m_ff)
    M = jnp.stack(
        [
            jnp.stack([m_kk, m_ks, m_ka]),
            jnp.stack([m_ks, m_ff, zero]),
            jnp.stack([m_ka, zero, m_ff]),
        ]
    )
    return M, jnp.stack([c_k, c_s, c_a]), -jnp.stack([g_k, g_s, g_a])


def _strain_deviation(params: HsaParams, xi: Array) -> Array:
    """beta_i - beta_eq,i for both rods, shape (2, 3) (model.md §6.4)."""
    kappa, sigma_sh, sigma_ax = xi[0], xi[1], xi[2]
    return jnp.stack(
        [
            kappa - params.kappa_b_eq,
            sigma_sh - params.sigma_sh_eq,
            sigma_ax + params.roff * kappa - params.sigma_a_eq,
        ],
        axis=-1,
    )


def _to_generalized(params: HsaParams, f_local: Array) -> Array:
    """sum_i J_beta,i^T f_i for per-rod local forces f (2, 3): [f_b + roff f_a, f_sh, f_a] summed
    over rods."""
    return jnp.stack(
        [
            jnp.sum(f_local[:, 0] + params.roff * f_local[:, 2]),
            jnp.sum(f_local[:, 1]),
            jnp.sum(f_local[:, 2]),
        ]
    )


def _elastic_of(params: HsaParams, xi: Array) -> Array:
    """K(xi) = sum_i J_beta,i^T S_hat_i (beta_i - beta_eq,i) (model.md §7.5)."""
    dev = _strain_deviation(params, xi)
    f = jnp.stack(
        [
            params.S_b_hat * dev[:, 0] + params.S_b_sh * dev[:, 1],
            params.S_b_sh * dev[:, 0] + params.S_sh_hat * dev[:, 1],
            params.S_a_hat * dev[:, 2],
        ],
        axis=-1,
    )
    return _to_generalized(params, f)


def _actuation_of(params: HsaParams, xi: Array, phi: Array) -> Array:
    """alpha(xi, phi) = sum_i J_beta,i^T [-S_delta,i (beta_i - beta_eq,i) + S_i [0, 0, eps_i]]
    (model.md §7.7)."""
    dev = _strain_deviation(params, xi)
    t = params.h * phi / params.l  # h_i phi_i / l
    f = jnp.stack(
        [
            -params.C_S_b * t * dev[:, 0],
            -params.C_S_sh * t * dev[:, 1],
            (params.S_a_hat + params.C_S_a * t) * params.C_eps * t - params.C_S_a * t * dev[:, 2],
        ],
        axis=-1,
    )
    return _to_generalized(params, f)


def _actuation_jacobian_of(params: HsaParams, xi: Array, phi: Array) -> Array:
    """A = d alpha / d phi (3x2) in closed form: column i is J_beta,i^T a_i (model.md §7.7)."""
    dev = _strain_deviation(params, xi)
    l, h = params.l, params.h
    a_b = -(h / l) * params.C_S_b * dev[:, 0]
    a_sh = -(h / l) * params.C_S_sh * dev[:, 1]
    a_ax = (h / l) * (
        params.S_a_hat * params.C_eps
        + 2.0 * params.C_S_a * params.C_eps * h * phi / l
        - params.C_S_a * dev[:, 2]
    )
    return jnp.stack([a_b + params.roff * a_ax, a_sh, a_ax])


def _constants(params: HsaParams) -> tuple[MassPoints, Array]:
    """Mass points and D: folded to constants with NumPy when params are concrete (closed over),
    else traced."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(params)):
        return mass_points(params), damping_matrix(params)
    concrete = jax.tree_util.tree_map(np.asarray, params)
    return mass_points(concrete, np), damping_matrix(concrete, np)


def _dynamic_strains(params: HsaParams, q: ArrayLike) -> Array:
    """Strains at which M, C, G, K, alpha and A are evaluated (shifted kappa in "exp2023_shift"
    mode)."""
    return apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_DYN)


def _as_f64(v: ArrayLike) -> Array:
    """Convert an input vector to a float64 JAX array."""
    return jnp.asarray(v, dtype=jnp.float64)


def mass_matrix(params: HsaParams, q: ArrayLike) -> Array:
    """Inertia matrix M(xi) (3x3, symmetric positive definite) of rods, platform and payload
    (model.md §7.2)."""
    return _inertial_terms(
        params, _constants(params)[0], _dynamic_strains(params, q), jnp.zeros(3)
    )[0]


def coriolis_matrix(params: HsaParams, q: ArrayLike, q_dot: ArrayLike) -> Array:
    """Coriolis/centrifugal matrix C(xi, q_dot) = sum_k Gamma_ijk q_dot_k; M_dot - 2C is
    skew-symmetric (§7.3)."""
    return _inertial_terms(
        params, _constants(params)[0], _dynamic_strains(params, q), _as_f64(q_dot)
    )[1]


def gravity_vector(params: HsaParams, q: ArrayLike) -> Array:
    """G = dU_g/dxi, the gravitational generalized force of rods, platform and payload (model.md
    §7.4)."""
    return _inertial_terms(
        params, _constants(params)[0], _dynamic_strains(params, q), jnp.zeros(3)
    )[2]


def gravitational_potential(params: HsaParams, q: ArrayLike) -> Array:
    """U_g(xi) = -sum_k m_k g^T p_k (J), the potential whose gradient is G; used for energy
    checks."""
    mp = _constants(params)[0]
    p = points_in_base(params, _dynamic_strains(params, q), mp.s, mp.d)
    return -jnp.sum(mp.m * (p @ params.g))


def elastic_potential(params: HsaParams, q: ArrayLike) -> Array:
    """U_e = sum_i (beta_i - beta_eq,i)^T S_hat_i (beta_i - beta_eq,i) / 2 (J), the potential of K
    at phi = 0."""
    dev = _strain_deviation(params, _dynamic_strains(params, q))
    quad = (
        params.S_b_hat * dev[:, 0] ** 2
        + 2.0 * params.S_b_sh * dev[:, 0] * dev[:, 1]
        + params.S_sh_hat * dev[:, 1] ** 2
        + params.S_a_hat * dev[:, 2] ** 2
    )
    return 0.5 * jnp.sum(quad)


def kinetic_energy(params: HsaParams, q: ArrayLike, q_dot: ArrayLike) -> Array:
    """T = q_dot^T M q_dot / 2 (J)."""
    q_dot = _as_f64(q_dot)
    return 0.5 * q_dot @ mass_matrix(params, q) @ q_dot


def elastic_force(params: HsaParams, q: ArrayLike) -> Array:
    """Twist-independent elastic force K(xi), linear in xi and zero at xi_eq (model.md §7.5)."""
    return _elastic_of(params, _dynamic_strains(params, q))


def damping_matrix(params: HsaParams, xp: ModuleType = jnp) -> Array:
    """Constant damping matrix D = sum_i J_beta,i^T diag(zeta_b, zeta_sh, zeta_a)_i J_beta,i
    (model.md §7.6)."""
    roff, zeta_a = params.roff, params.zeta_a
    d02 = (roff * zeta_a).sum()
    zero = xp.zeros(())
    return xp.stack(
        [
            xp.stack([(params.zeta_b + roff**2 * zeta_a).sum(), zero, d02]),
            xp.stack([zero, params.zeta_sh.sum(), zero]),
            xp.stack([d02, zero, zeta_a.sum()]),
        ]
    )


def actuation_force(params: HsaParams, q: ArrayLike, phi: ArrayLike) -> Array:
    """Actuation force alpha(xi, phi), quadratic in phi and zero at phi = 0 (model.md §7.7)."""
    return _actuation_of(params, _dynamic_strains(params, q), _as_f64(phi))


def actuation_jacobian(params: HsaParams, q: ArrayLike, phi: ArrayLike) -> Array:
    """A = d alpha / d phi (3x2) in closed form; column i is J_beta,i^T a_i (model.md §7.7)."""
    return _actuation_jacobian_of(params, _dynamic_strains(params, q), _as_f64(phi))


def collocated_map(params: HsaParams, q: ArrayLike, phi_ss: ArrayLike) -> Array:
    """Collocated coordinates varphi = h(xi; phi_ss) = [varphi_1, varphi_2, sigma_sh], always at the
    exact xi (P&C §3.2)."""
    xi = strains(params, q)
    kappa, sigma_sh, sigma_ax = xi[0], xi[1], xi[2]
    l, h = params.l, params.h
    s_ax = sigma_ax + params.roff * kappa
    varphi_rods = (h / l) * (
        (
            params.S_a_hat * params.C_eps
            + 2.0 * params.C_S_a * params.C_eps * h * _as_f64(phi_ss) / l
        )
        * s_ax
        - params.C_S_a * (s_ax**2 / 2.0 - params.sigma_a_eq * s_ax)
        - params.C_S_b * (kappa**2 / 2.0 - params.kappa_b_eq * kappa)
        - params.C_S_sh * (sigma_sh**2 / 2.0 - params.sigma_sh_eq * sigma_sh)
    )
    return jnp.concatenate([varphi_rods, sigma_sh[None]])


def collocated_jacobian(params: HsaParams, q: ArrayLike, phi_ss: ArrayLike) -> Array:
    """J_h = d varphi / d q (3x3) by autodiff; rows 1-2 equal A^T at the exact xi, row 3 is [0, 1,
    0] (P&C §3.2)."""
    return jax.jacfwd(collocated_map, argnums=1)(params, _as_f64(q), phi_ss)


def static_residual(params: HsaParams, q: ArrayLike, phi: ArrayLike) -> Array:
    """G + K - alpha: zero at a static equilibrium of configuration q under the constant twist
    phi."""
    xi = _dynamic_strains(params, q)
    G = _gravity_of(params, _constants(params)[0], xi)
    return G + _elastic_of(params, xi) - _actuation_of(params, xi, _as_f64(phi))


def dynamical_matrices(
    params: HsaParams, q: ArrayLike, q_dot: ArrayLike, phi: ArrayLike
) -> DynamicalMatrices:
    """All terms M, C, G, K, D, alpha, A of the equation of motion at (q, q_dot, phi) in one pass
    (model.md §7)."""
    xi = _dynamic_strains(params, q)
    phi = _as_f64(phi)
    M, C, G = _inertial_terms(params, _constants(params)[0], xi, _as_f64(q_dot))
    return DynamicalMatrices(
        M=M,
        C=C,
        G=G,
        K=_elastic_of(params, xi),
        D=_constants(params)[1],
        alpha=_actuation_of(params, xi, phi),
        A=_actuation_jacobian_of(params, xi, phi),
    )


def forward_dynamics_fn(params: HsaParams) -> Callable[[ArrayLike, ArrayLike, ArrayLike], Array]:
    """(q, q_dot, phi) -> q_ddot with the parameter-only terms (mass points, D) computed once, for
    use inside loops."""
    mp, D = _constants(params)

    def q_ddot(q: ArrayLike, q_dot: ArrayLike, phi: ArrayLike) -> Array:
        xi, q_dot, phi = _dynamic_strains(params, q), _as_f64(q_dot), _as_f64(phi)
        M, C_q_dot, G = _inertial_forces(params, mp, xi, q_dot)
        rhs = (
            _actuation_of(params, xi, phi)
            - C_q_dot
            - G
            - _elastic_of(params, xi)
            - jnp.sum(D * q_dot, axis=1)
        )
        return solve3(M, rhs)

    return jax.jit(q_ddot)  # traced once per use, however many RK4 stages call it (XLA inlines it)


def solve3(M: Array, b: Array) -> Array:
    """x = M⁻¹ b for a 3x3 M by its adjugate, M⁻¹ = [r1×r2 | r2×r0 | r0×r1] / det (r_i: rows of M).

    At this size a LAPACK solve is two thirds of a dynamics evaluation on the CPU (a call per
    matrix); the closed form is a few dozen flops that XLA fuses and vectorises over a batch. For
    the mass matrix (symmetric positive definite) the result agrees with the LU solve to round-off
    times its condition number (tests/core/test_dynamics.py).
    """
    c0, c1, c2 = jnp.cross(M[1], M[2]), jnp.cross(M[2], M[0]), jnp.cross(M[0], M[1])
    return (c0 * b[0] + c1 * b[1] + c2 * b[2]) / jnp.dot(M[0], c0)


def forward_dynamics(params: HsaParams, q: ArrayLike, q_dot: ArrayLike, phi: ArrayLike) -> Array:
    """q_ddot = M^-1 (alpha - C q_dot - G - K - D q_dot) by a linear solve, never an explicit
    inverse (§7.1)."""
    return forward_dynamics_fn(params)(q, q_dot, phi)

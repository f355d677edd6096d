"""Smooth functions, forward/inverse kinematics, strains and the exp2023 kinematic shift (model.md
§6, §8, §10)."""

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_core.model import kinematics as kin
from hsa_core.model.params import HsaParams
from hsa_core.model.smooth import X_T, C, S, T, arc_functions, c
from tests.core.conftest import REFERENCE, assert_printed, params_for

# --------------------------------------------------------------------------------------------------
# smooth entire functions (model.md §8.2)

CLOSED = {
    "S": (S, lambda x: math.sin(x) / x),
    "C": (C, lambda x: (1 - math.cos(x)) / x**2),
    "T": (T, lambda x: (x - math.sin(x)) / x**3),
    "c": (c, lambda x: (x / 2) / math.tan(x / 2)),
}
AT_ZERO = {
    "S": (1.0, -1 / 3),
    "C": (0.5, -1 / 12),
    "T": (1 / 6, -1 / 60),
    "c": (1.0, -1 / 6),  # f(0), f''(0)
}


@pytest.mark.parametrize("name", CLOSED)
def test_smooth_functions_match_closed_forms_and_are_exact_at_zero(name: str) -> None:
    f, closed = CLOSED[name]
    values = jax.jit(jax.vmap(jax.value_and_grad(jax.grad(f))))
    x = [0.3, -0.7, 1.0, 2.5, -3.0, 5.0, 0.05, -0.099, 0.0]
    (d1, d2) = (np.asarray(v) for v in values(jnp.asarray(x)))
    got = np.asarray(jax.jit(jax.vmap(f))(jnp.asarray(x)))
    np.testing.assert_allclose(got[:6], [closed(v) for v in x[:6]], rtol=1e-14)
    # below the threshold the series is used; closed forms there are still accurate to ~1e-12 at
    # these arguments
    np.testing.assert_allclose(got[6:8], [closed(v) for v in x[6:8]], rtol=1e-12)
    value0, curvature0 = AT_ZERO[name]
    assert got[8] == value0 and d1[8] == 0.0
    assert d2[8] == pytest.approx(curvature0, rel=1e-15)


@pytest.mark.parametrize("name", CLOSED)
def test_smooth_functions_are_continuous_across_the_threshold(name: str) -> None:
    f = CLOSED[name][0]
    derivs = jax.jit(
        jax.vmap(lambda x: jnp.stack([f(x), jax.grad(f)(x), jax.grad(jax.grad(f))(x)]))
    )
    for sign in (1.0, -1.0):
        below, above = np.asarray(derivs(jnp.array([sign * X_T * (1 - 1e-13), sign * X_T])))
        # the closed forms lose ~eps/x^k at x = 0.1 in their k-th derivative (T suffers most: (x -
        # sin x)/x^3)
        for order, (rtol, atol) in enumerate([(1e-12, 1e-15), (5e-10, 1e-13), (1e-8, 0.0)]):
            assert below[order] == pytest.approx(above[order], rel=rtol, abs=atol), (
                order,
                below,
                above,
            )


def test_smooth_functions_give_finite_gradients_at_zero() -> None:
    x = jnp.array([0.0, 1e-300, -1e-12, 0.1, 2.0])

    @jax.jit
    def all_derivatives(v):
        out = []
        for f in (S, C, T, c):
            out += [jax.vmap(jax.grad(f))(v), jax.jacrev(f)(v), jax.jacfwd(jax.jacfwd(f))(v)]
        return out

    assert all(np.all(np.isfinite(d)) for d in all_derivatives(x))


@jax.jit
def _arc_functions_and_reference(x):
    """arc_functions(x) and the same values from autodiff of S and x C (first and second
    derivatives)."""

    def e(y):
        return jnp.stack([S(y), y * C(y)])

    def derivatives(y):
        d1 = jax.jacfwd(e)(y)
        return jnp.stack(
            [
                e(y)[0],
                d1[0],
                jax.jacfwd(jax.jacfwd(e))(y)[0],
                e(y)[1],
                d1[1],
                jax.jacfwd(jax.jacfwd(e))(y)[1],
            ]
        )

    return arc_functions(x), jax.vmap(derivatives)(x).T, jax.vmap(jax.jacfwd(arc_functions))(x).T


def test_arc_functions_are_E_and_its_derivatives() -> None:
    x = jnp.array([0.0, 1e-9, -0.03, 0.0999999, 0.1, -0.1, 0.5, -1.7, 3.0, 9.0])
    values, reference, jac = (np.asarray(a) for a in _arc_functions_and_reference(x))
    # [S, S', S'', B, B', B''] with B = x C; the closed forms lose ~eps / x^2 in their second
    # derivatives near 0.1
    np.testing.assert_allclose(values[:6], reference, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(values[6:], [np.cos(x), np.sin(x)], rtol=1e-15, atol=1e-16)
    np.testing.assert_array_equal(values[:, 0], [1.0, 0.0, -1 / 3, 0.0, 0.5, 0.0, 1.0, 0.0])
    # each function's autodiff derivative is the next one (so the dynamics can be differentiated
    # once more)
    for f, df in ((0, 1), (1, 2), (3, 4), (4, 5)):
        np.testing.assert_allclose(jac[f], values[df], rtol=1e-11, atol=1e-14)
    assert np.all(np.isfinite(jac))


# --------------------------------------------------------------------------------------------------
# forward kinematics


def test_rest_pose_and_backbone_geometry(fpu: HsaParams) -> None:
    np.testing.assert_allclose(
        kin.end_effector_pose(fpu, jnp.zeros(3)), [0.0, 0.110, 0.0], atol=1e-16
    )
    np.testing.assert_allclose(
        kin.backbone_pose(fpu, jnp.zeros(3), 0.0), [0.0, 0.025, 0.0], atol=1e-16
    )
    np.testing.assert_allclose(
        kin.rod_positions(fpu, jnp.zeros(3), 0.0), [[-0.024, 0.025], [0.024, 0.025]], atol=1e-16
    )
    # platform CoG 18.9231 mm below the end of the active length (model.md §5.2)
    np.testing.assert_allclose(
        kin.platform_pose(fpu, jnp.zeros(3)), [0.0, 0.025 + 0.059 + 18.9231e-3, 0.0], atol=5e-8
    )
    # kappa = 0: straight sheared line p(s) = [sigma_sh s, l_pc + sigma_ax s] (model.md §6.1)
    q = jnp.array([0.0, 0.02, 0.3])
    np.testing.assert_allclose(
        kin.backbone_pose(fpu, q, 0.04), [0.02 * 0.04, 0.025 + 1.3 * 0.04, 0.0], rtol=1e-15
    )


def test_smooth_backbone_equals_the_closed_form_for_nonzero_curvature(fpu: HsaParams) -> None:
    kappa, sigma_sh, sigma_ax = 7.3, 0.03, 1.2
    q = jnp.array([kappa, sigma_sh, sigma_ax - 1.0])
    s = np.linspace(0.0, 0.059, 7)[1:]
    px = (sigma_sh * np.sin(kappa * s) - sigma_ax * (1 - np.cos(kappa * s))) / kappa
    py = 0.025 + (sigma_sh * (1 - np.cos(kappa * s)) + sigma_ax * np.sin(kappa * s)) / kappa
    pose = np.asarray(kin.backbone_pose(fpu, q, jnp.asarray(s)))
    np.testing.assert_allclose(pose, np.stack([px, py, kappa * s], axis=1), rtol=1e-13, atol=1e-17)
    # rods: p_i = p + R(theta) [roff_i, 0]; their distance to the backbone is |roff|
    rods = np.asarray(kin.rod_positions(fpu, q, jnp.asarray(s)))
    assert rods.shape == (6, 2, 2)
    np.testing.assert_allclose(np.linalg.norm(rods - pose[:, None, :2], axis=-1), 0.024, rtol=1e-13)
    np.testing.assert_allclose(rods[:, 0, 0] - pose[:, 0], -0.024 * np.cos(kappa * s), rtol=1e-12)


def test_end_effector_geometry_with_offset(fpu: HsaParams) -> None:
    p = fpu.replace(chiee_off=[0.003, 0.025, 0.2])
    q = jnp.array([-4.0, 0.01, 0.2])
    kappa_l = -4.0 * 0.059
    tip = np.asarray(kin.backbone_pose(p, q, 0.059))
    rot = np.array(
        [[math.cos(kappa_l), -math.sin(kappa_l)], [math.sin(kappa_l), math.cos(kappa_l)]]
    )
    expected = tip[:2] + rot @ np.array([0.003, 0.014 + 0.012 + 0.025])
    np.testing.assert_allclose(kin.end_effector_pose(p, q), [*expected, kappa_l + 0.2], rtol=1e-14)
    cog = tip[:2] + rot @ np.array([0.0, float(p.y_c)])
    np.testing.assert_allclose(kin.platform_pose(p, q), [*cog, kappa_l], rtol=1e-14)


@pytest.mark.parametrize("case", ["R1", "R2", "R3", "R4"])
def test_reference_end_effector_poses(case: str) -> None:
    ref = REFERENCE[case]
    q = jnp.asarray(ref["q"])
    exact = kin.end_effector_pose(params_for(ref["material"]), q)
    assert_printed(exact, ref["exact"]["chiee"], atol=1e-17, name="exact chiee")
    shifted = kin.end_effector_pose(params_for(ref["material"], "exp2023_shift"), q)
    if (
        case == "R1"
    ):  # kappa_kin = +1e-6 at q = 0; the reference itself carries cancellation error (§10 R1)
        assert_printed(shifted, ref["compat"]["chiee"], rtol=1e-7, atol=1e-17, name="compat chiee")
        np.testing.assert_allclose(shifted, ref["reference"]["chiee"], rtol=0, atol=1e-10)
    else:
        assert_printed(shifted, ref["reference"]["chiee"], name="reference chiee")


def test_exp2023_kinematic_shift_rule(fpu: HsaParams, model) -> None:
    shift = fpu.replace(kappa_rule="exp2023_shift")
    for kappa, shifted in [(0.0, 1e-6), (2.0, 2.0 + 1e-6), (-3.0, -3.0 - 1e-6)]:  # sign(0) = +1
        q = jnp.array([kappa, 0.01, 0.1])
        np.testing.assert_array_equal(model.fk(shift, q), model.fk(fpu, q.at[0].set(shifted)))
        np.testing.assert_array_equal(model.jee(shift, q), model.jee(fpu, q.at[0].set(shifted)))


def test_end_effector_jacobian_matches_central_differences(fpu: HsaParams, model) -> None:
    rng = np.random.default_rng(3)
    for q in [np.zeros(3), *rng.uniform([-20, -0.05, -0.1], [20, 0.05, 0.6], size=(5, 3))]:
        J = np.asarray(model.jee(fpu, jnp.asarray(q)))
        eps = 1e-6
        fd = np.stack(
            [
                (model.fk(fpu, jnp.asarray(q + eps * e)) - model.fk(fpu, jnp.asarray(q - eps * e)))
                / (2 * eps)
                for e in np.eye(3)
            ],
            axis=1,
        )
        np.testing.assert_allclose(J, fd, rtol=1e-7, atol=1e-10)
    # the exact EE Jacobian at q = 0: d theta / d kappa = l, dx/dkappa = -(l^2/2 + l (l_dc + h_p))
    # for sigma_ax = 1
    J0 = np.asarray(model.jee(fpu, jnp.zeros(3)))
    np.testing.assert_allclose(
        J0[:, 0], [-(0.059**2 / 2 + 0.059 * 0.026), 0.0, 0.059], rtol=1e-14, atol=1e-18
    )
    np.testing.assert_allclose(
        J0[:, 1:], [[0.059, 0.0], [0.0, 0.059], [0.0, 0.0]], rtol=1e-14, atol=1e-18
    )


# --------------------------------------------------------------------------------------------------
# inverse kinematics (model.md §6.3)


def _workspace_samples(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.uniform([-45.0, -0.1, -0.2], [45.0, 0.1, 0.8], size=(n, 3))  # |theta_ee| up to 2.7 rad
    q[:4, 0] = [
        0.0,
        1e-9,
        -1e-9,
        0.1 / 0.059,  # exactly straight, nearly straight, and at the series threshold
    ]
    return q


@jax.jit
@partial(jax.vmap, in_axes=(None, 0))
def _round_trips(params: HsaParams, q):
    """IK(FK(q)) and FK(IK(FK(q)))."""
    chiee = kin.end_effector_pose(params, q)
    q_back = kin.inverse_kinematics(params, chiee)
    return q_back, chiee, kin.end_effector_pose(params, q_back)


@pytest.mark.parametrize("variant", ["nominal", "calibrated_with_offset"])
def test_ik_inverts_fk_over_the_workspace(fpu: HsaParams, variant: str) -> None:
    p = (
        fpu
        if variant == "nominal"
        else fpu.replace(sigma_a_eq=[1.0544, 1.0447], chiee_off=[0.002, 0.025, -0.3])
    )
    q = _workspace_samples(200, 11)
    q_back, chiee, chiee_back = (np.asarray(a) for a in _round_trips(p, jnp.asarray(q)))
    err = np.abs(q_back - q)
    assert err[:, 0].max() < 1e-12 * 45 and err[:, 1:].max() < 1e-12, err.max(axis=0)
    assert abs(q_back[0, 0]) < 1e-13  # exactly straight stays straight
    np.testing.assert_allclose(chiee_back, chiee, rtol=0, atol=1e-15)


def test_ik_gradients_are_finite_and_continuous_at_zero_angle(fpu: HsaParams) -> None:
    ik = lambda chi: kin.inverse_kinematics(fpu, chi)  # noqa: E731
    jac, hess = jax.jit(jax.jacfwd(ik)), jax.jit(jax.jacfwd(jax.jacfwd(ik)))
    base = np.array([0.001, 0.12, 0.0])
    J0, H0 = np.asarray(jac(jnp.asarray(base))), np.asarray(hess(jnp.asarray(base)))
    assert np.all(np.isfinite(J0)) and np.all(np.isfinite(H0))
    for th in (-1e-9, 1e-9):  # first-order Taylor: J(th) = J(0) + th dJ/dth + O(th^2)
        np.testing.assert_allclose(
            jac(jnp.asarray(base + [0, 0, th])), J0 + th * H0[:, :, 2], rtol=0, atol=1e-15
        )
    # across the series / closed-form switch of c(theta) at |theta| = 0.1
    for th in (0.1, -0.1):
        lo, hi = (np.asarray(jac(jnp.asarray(base + [0, 0, th * f]))) for f in (1 - 1e-12, 1.0))
        np.testing.assert_allclose(lo, hi, rtol=1e-9, atol=1e-12)
    assert np.all(np.isfinite(jax.grad(lambda chi: jnp.sum(ik(chi) ** 2))(jnp.asarray(base))))


def test_fk_and_jee_are_continuous_across_zero_and_the_threshold(fpu: HsaParams, model) -> None:
    hess = jax.jit(jax.jacfwd(kin.end_effector_jacobian, argnums=1))
    base = np.array([0.0, 0.01, 0.2])
    fk0, J0, H0 = (
        model.fk(fpu, base),
        np.asarray(model.jee(fpu, base)),
        np.asarray(hess(fpu, jnp.asarray(base))),
    )
    assert np.all(np.isfinite(H0))
    for k in (-1e-9, 1e-9):  # first-order Taylor around kappa = 0 from both sides
        q = base + [k, 0, 0]
        np.testing.assert_allclose(model.fk(fpu, q), fk0 + k * J0[:, 0], rtol=0, atol=1e-18)
        np.testing.assert_allclose(model.jee(fpu, q), J0 + k * H0[:, :, 0], rtol=0, atol=1e-17)
    kappa_t = X_T / 0.059  # kappa at which x = kappa l crosses the switch
    for sign in (1.0, -1.0):
        lo, hi = base + [sign * kappa_t * (1 - 1e-13), 0, 0], base + [sign * kappa_t, 0, 0]
        np.testing.assert_allclose(model.fk(fpu, lo), model.fk(fpu, hi), rtol=1e-12, atol=1e-16)
        np.testing.assert_allclose(model.jee(fpu, lo), model.jee(fpu, hi), rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(
            hess(fpu, jnp.asarray(lo)), hess(fpu, jnp.asarray(hi)), rtol=1e-8, atol=1e-12
        )


def test_kinematics_jit_vmap_grad(fpu: HsaParams) -> None:
    q = jnp.asarray(_workspace_samples(16, 5))
    batched = jax.jit(jax.vmap(kin.end_effector_pose, in_axes=(None, 0)))(fpu, q)
    single = np.stack([np.asarray(kin.end_effector_pose(fpu, qi)) for qi in q])
    np.testing.assert_allclose(batched, single, rtol=1e-15, atol=1e-18)
    g = jax.grad(lambda qi: kin.end_effector_pose(fpu, qi)[0])(jnp.zeros(3))
    assert np.all(np.isfinite(g))
    # gradient with respect to the parameters (identification / calibration use)
    gp = jax.grad(lambda p: kin.end_effector_pose(p, jnp.zeros(3))[1])(fpu)
    assert float(gp.l) == pytest.approx(1.0) and float(gp.l_pc) == pytest.approx(1.0)


# --------------------------------------------------------------------------------------------------
# strains and twist (model.md §6.4)


def test_rod_strains_and_twist_elongation(fpu: HsaParams) -> None:
    q = jnp.array([5.0, 0.02, 0.1])
    np.testing.assert_allclose(
        kin.rod_strains(fpu, q),
        [[5.0, 0.02, 1.1 - 0.024 * 5.0], [5.0, 0.02, 1.1 + 0.024 * 5.0]],
        rtol=1e-15,
    )
    p = fpu.replace(sigma_a_eq=[1.05, 1.04])  # q is relative to the calibrated rest strains
    np.testing.assert_allclose(
        kin.rod_strains(p, jnp.zeros(3))[:, 2], [1.045 - 0.0, 1.045], rtol=1e-15
    )
    eps = kin.twist_elongation(fpu, jnp.array([math.pi, 0.0]))
    # FPU example of §6.4
    assert float(eps[0]) == pytest.approx(0.524, abs=5e-4) and float(eps[1]) == 0.0

"""Steady-state planning (planning_and_control.md §2): the worked examples of §2.2 and §2.3, the
step lists of experiments.md §2, kappa = 0 targets, rollout / static agreement for the EPU, and
clear failures."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import load_params
from hsa_core.task import planning
from hsa_core.task.planning import Planner, PlannerKind, PlanStatus
from hsa_core.task.trajectories import STEP_LISTS

FPU_STEPS, EPU_STEPS = (
    STEP_LISTS["fpu"],
    STEP_LISTS["epu"],  # experiments.md §2 (2023-09-25 and 2023-10-19)
)
FPU_PHI_MAX, EPU_PHI_MAX = np.radians(200.0), np.radians(270.0)
SPEC_RTOL = 5e-8  # the spec prints 8 significant digits: rounding error <= 5e-8 relative

static_residual = jax.jit(dynamics.static_residual)
ee_pose = jax.jit(kinematics.end_effector_pose)
ee_jacobian = jax.jit(kinematics.end_effector_jacobian)
actuation_jacobian = jax.jit(dynamics.actuation_jacobian)
stiffness = jax.jit(jax.jacfwd(dynamics.static_residual, argnums=1))


@pytest.fixture(scope="module")
def fpu():
    return Planner(load_params("fpu"))


@pytest.fixture(scope="module")
def epu():
    return Planner(load_params("epu"))


@pytest.fixture(scope="module")
def fpu_reference():
    return Planner(load_params("fpu", kappa_rule="exp2023_shift"))


@pytest.fixture(scope="module")
def epu_rollout():
    return Planner(load_params("epu"), "rollout")


def check_setpoint(params, result, p_des, phi_max, tol=1e-9):
    """Independent checks of a successful plan: static residual, FK of q^d, range of phi^ss."""
    assert result.success and result.status is PlanStatus.OK, result.message
    sp = result.setpoint
    residual = np.linalg.norm(static_residual(params, sp.q_des, sp.phi_ss))
    assert residual <= tol
    assert result.optimality_error <= tol
    np.testing.assert_allclose(ee_pose(params, sp.q_des), sp.chiee_des, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.chiee_des[:2], p_des, rtol=0, atol=1e-12)
    assert np.all(sp.phi_ss >= 0.0) and np.all(sp.phi_ss <= phi_max)


# planning_and_control.md §2.2: p^d, theta*, q^d, phi^ss
EXACT_ROWS = [
    (
        [0.00479247, 0.12781018],
        -0.066980133,
        [-1.1352565, 0.0080816386, 0.30410104],
        [1.9846028, 1.6323408],
    ),
    ([-0.035, 0.122], 0.49924063, [8.4617057, -0.060452706, 0.32637070], [0.63282860, 3.2426909]),
]
REFERENCE_ROWS = [
    (
        [0.00479247, 0.12781018],
        -0.066920814,
        [-1.1342680, 0.0081457929, 0.30409951],
        [1.9859904, 1.6309320],
    ),
    ([-0.035, 0.122], 0.49918097, [8.4607113, -0.060517208, 0.32635912], [0.63135656, 3.2440052]),
]


@pytest.mark.parametrize(("p_des", "theta", "q_des", "phi_ss"), EXACT_ROWS)
def test_static_inversion_worked_examples_exact(fpu, p_des, theta, q_des, phi_ss):
    result = fpu.plan(p_des, warm_start=False)
    check_setpoint(fpu.params, result, p_des, FPU_PHI_MAX, tol=1e-13)
    sp = result.setpoint
    np.testing.assert_allclose(sp.chiee_des[2], theta, rtol=SPEC_RTOL)
    np.testing.assert_allclose(sp.q_des, q_des, rtol=SPEC_RTOL)
    np.testing.assert_allclose(sp.phi_ss, phi_ss, rtol=SPEC_RTOL)


@pytest.mark.parametrize(("p_des", "theta", "q_des", "phi_ss"), REFERENCE_ROWS)
def test_static_inversion_worked_examples_reference(fpu_reference, p_des, theta, q_des, phi_ss):
    """exp2023 kappa rule: >= 6 digits in phi^ss and q^d; theta* to 1e-6 rad (the original IK shifts
    theta by 1e-6)."""
    result = fpu_reference.plan(p_des, warm_start=False)
    assert result.status is PlanStatus.OK and result.optimality_error <= 1e-10
    sp = result.setpoint
    np.testing.assert_allclose(sp.phi_ss, phi_ss, rtol=3e-6)
    np.testing.assert_allclose(sp.q_des, q_des, rtol=1e-5)
    np.testing.assert_allclose(sp.chiee_des[2], theta, rtol=0, atol=1e-6)


def test_reference_rule_near_zero_curvature_is_accepted_like_the_original(fpu_reference):
    """§2.1: with the kappa shift the residual at x = 0 cannot vanish; ~2e-4 is accepted, phi^ss
    nearly symmetric."""
    result = fpu_reference.plan([0.0, 0.120], warm_start=False)
    assert result.status is PlanStatus.OK
    assert 1e-6 < result.optimality_error < 1e-3
    np.testing.assert_allclose(result.setpoint.phi_ss[0], result.setpoint.phi_ss[1], atol=2e-3)


@pytest.mark.parametrize("warm", [False, True])
def test_fpu_step_points(fpu, warm):
    fpu.reset_warm_start()
    for p_des in FPU_STEPS:
        check_setpoint(fpu.params, fpu.plan(p_des, warm_start=warm), p_des, FPU_PHI_MAX)


def test_epu_step_points_default_planner_is_bounded_static(epu):
    assert epu.kind == "static"
    for p_des in EPU_STEPS:
        check_setpoint(epu.params, epu.plan(p_des, warm_start=False), p_des, EPU_PHI_MAX)


@pytest.mark.parametrize("p_des", [[0.0, 0.120], [0.0, 0.140], [0.0, 0.1102]])
def test_zero_curvature_targets_give_symmetric_phi(fpu, p_des):
    result = fpu.plan(p_des, warm_start=False)
    check_setpoint(fpu.params, result, p_des, FPU_PHI_MAX, tol=1e-12)
    sp = result.setpoint
    np.testing.assert_allclose(sp.phi_ss[0], sp.phi_ss[1], rtol=0, atol=1e-12)
    assert abs(sp.chiee_des[2]) < 1e-12 and abs(sp.q_des[0]) < 1e-10


def test_epu_rollout_forward_worked_example(epu_rollout):
    """§2.3 forward, exact model: phi = [3.97701721, 2.51175997] held 5 s from rest."""
    x = np.asarray(planning.rollout_steady_state(epu_rollout.params, [3.97701721, 2.51175997]))
    np.testing.assert_allclose(x[:3], [-3.8771193, 0.0016986055, 0.44729103], rtol=SPEC_RTOL)
    assert np.linalg.norm(x[3:]) < 1e-8
    chiee = ee_pose(epu_rollout.params, x[:3])
    np.testing.assert_allclose(chiee, [0.015719103, 0.13495872, -0.22875004], rtol=SPEC_RTOL)


def test_epu_rollout_planner_inverse_worked_example(epu_rollout):
    """§2.3 inverse, exact model, target = first EPU step point."""
    result = epu_rollout.plan(EPU_STEPS[0], warm_start=False)
    assert result.status is PlanStatus.OK and result.planner == "rollout"
    assert result.planner is PlannerKind.ROLLOUT and epu_rollout.kind is PlannerKind.ROLLOUT
    assert result.optimality_error <= 1e-9  # [m]
    np.testing.assert_allclose(result.setpoint.phi_ss, [3.9751574, 2.5136546], rtol=SPEC_RTOL)
    np.testing.assert_allclose(
        result.setpoint.q_des, [-3.8671868, 0.0016940858, 0.44729129], rtol=SPEC_RTOL
    )


def test_bounded_static_inversion_equals_rollout_planning_on_epu_steps(epu, epu_rollout):
    """§2.3: the 5 s rollout at the static phi^ss ends on p^d, so both planners have the same
    phi^ss.

    The EE error of the rollout at the static solution, mapped through the steady-state sensitivity,
    bounds the phi difference to one rollout-LM step: required < 1e-6 rad, three orders below one
    encoder tick (1.53e-3 rad).
    """
    for p_des in EPU_STEPS:
        phi_static = epu.plan(p_des, warm_start=False).setpoint.phi_ss
        x = np.asarray(planning.rollout_steady_state(epu.params, phi_static))
        error = np.asarray(ee_pose(epu.params, x[:3]))[:2] - p_des
        K_t = stiffness(epu.params, x[:3], phi_static)
        S = ee_jacobian(epu.params, x[:3])[:2] @ np.linalg.solve(
            K_t, actuation_jacobian(epu.params, x[:3], phi_static)
        )
        assert np.linalg.norm(np.linalg.solve(S, error)) < 1e-6


def test_equilibrium_planner_matches_static_and_is_stable(epu):
    eq = Planner(epu.params, "equilibrium")
    for p_des in (EPU_STEPS[0], EPU_STEPS[7], [0.0, 0.13]):
        a, b = eq.plan(p_des), epu.plan(p_des, warm_start=False)
        assert a.status is PlanStatus.OK and a.planner == "equilibrium"
        np.testing.assert_allclose(a.setpoint.phi_ss, b.setpoint.phi_ss, rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.setpoint.q_des, b.setpoint.q_des, rtol=0, atol=1e-9)


def test_static_equilibrium_and_linearisation_against_spec(fpu):
    """model.md §10 S1 (steady state for phi = [2, 3]) and §9.4 (eigenvalues at phi = 0)."""
    q, residual = planning.static_equilibrium(fpu.params, [2.0, 3.0], np.zeros(3))
    np.testing.assert_allclose(q, [3.3248719, -0.023905921, 0.41951499], rtol=SPEC_RTOL)
    assert residual <= 1e-12
    q0, _ = planning.static_equilibrium(fpu.params, [0.0, 0.0], np.zeros(3))
    eig = np.linalg.eigvals(
        np.asarray(jax.jit(planning.linearization)(fpu.params, q0, np.zeros(2)))
    )
    expected = [-731, -143, -130 + 238j, -130 - 238j, -8.4 + 76.8j, -8.4 - 76.8j]
    for e in expected:
        assert np.min(np.abs(eig - e)) < 0.01 * abs(e) + 0.1


def test_warm_start_tracks_a_contour_with_fewer_iterations(fpu):
    """Continuous (image) mode: points 1 mm apart on a circle; warm starts give the same setpoints
    faster."""
    angles = np.linspace(0.0, 2.0 * np.pi, 40)
    contour = np.stack([0.013 * np.cos(angles), 0.127 + 0.013 * np.sin(angles)], axis=1)
    fpu.reset_warm_start()
    warm = [fpu.plan(p) for p in contour]
    cold = [fpu.plan(p, warm_start=False) for p in contour]
    for w, c, p in zip(warm, cold, contour):
        check_setpoint(fpu.params, w, p, FPU_PHI_MAX)
        np.testing.assert_allclose(w.setpoint.phi_ss, c.setpoint.phi_ss, rtol=0, atol=1e-10)
    assert np.mean([w.iterations for w in warm[1:]]) < np.mean([c.iterations for c in cold[1:]])


@pytest.mark.parametrize("p_des", [[0.2, 0.1], [0.0, 0.3], [0.0, 0.17], [-0.1, 0.05]])
def test_far_targets_are_rejected_fast(fpu, p_des):
    result = fpu.plan(p_des)
    assert (
        not result.success and result.status is PlanStatus.UNREACHABLE and result.setpoint is None
    )
    assert "outside" in result.message and result.iterations == 0  # no solver call
    assert result.solve_time_s < 5e-3


@pytest.mark.parametrize(
    "p_des",
    [
        [0.0, 0.105],  # above the rest pose (y = 0.11014 m): would need negative twist
        [0.045, 0.118],  # bent further than phi1 = phi_max, phi2 = 0 allows
    ],
)
def test_targets_needing_phi_outside_the_limits_fail_with_phi_out_of_range(fpu, p_des):
    assert fpu.in_reach_region(p_des)  # inside the conservative region: the solver decides
    result = fpu.plan(p_des)
    assert (
        not result.success
        and result.status is PlanStatus.PHI_OUT_OF_RANGE
        and result.setpoint is None
    )
    assert "phi" in result.message


@pytest.mark.parametrize(
    "p_des", [[np.nan, 0.12], [0.0, np.inf], [0.0], [0.0, 0.12, 0.0], "xy", None]
)
def test_invalid_requests(fpu, p_des):
    result = fpu.plan(p_des)
    assert (
        not result.success
        and result.status is PlanStatus.INVALID_REQUEST
        and result.setpoint is None
    )


def test_failures_do_not_poison_the_warm_start(fpu):
    fpu.plan(FPU_STEPS[1])
    assert fpu.plan([0.0, 0.105]).status is PlanStatus.PHI_OUT_OF_RANGE
    check_setpoint(fpu.params, fpu.plan(FPU_STEPS[2]), FPU_STEPS[2], FPU_PHI_MAX)


def test_unknown_planner_kind_is_refused():
    with pytest.raises(ValueError, match="planner kind"):
        Planner(load_params("fpu"), "gradient")


def test_reachability_region_contains_every_equilibrium(fpu):
    """The fast rejection is conservative: equilibria at random phi in the box (incl. corners) are
    never rejected."""
    rng = np.random.default_rng(1)
    phis = np.vstack(
        [rng.uniform(0.0, FPU_PHI_MAX, (40, 2)), [[0, 0], [0, FPU_PHI_MAX], [FPU_PHI_MAX, 0]]]
    )
    for phi in phis:
        q, _ = planning.static_equilibrium(fpu.params, phi, np.zeros(3))
        assert fpu.in_reach_region(np.asarray(ee_pose(fpu.params, q))[:2])


@pytest.mark.slow
def test_rollout_lm_from_zero_twist_with_forward_mode_jacobian(epu):
    """§2.3 as in the original: rollout LM from phi0 = [0, 0] (uses the forward-mode Jacobian
    through the rollout).

    Its Jacobian equals J_ee K_t^-1 A at the reached equilibrium, and it converges to the spec's
    inverse solution.
    """
    phi = np.array([3.97701721, 2.51175997])
    J = np.asarray(planning._rollout_jacobian(epu.params, phi))
    q = np.asarray(planning.rollout_steady_state(epu.params, phi))[:3]
    S = ee_jacobian(epu.params, q)[:2] @ np.linalg.solve(
        stiffness(epu.params, q, phi), actuation_jacobian(epu.params, q, phi)
    )
    np.testing.assert_allclose(J, S, rtol=1e-6, atol=1e-9)
    lo, hi = np.zeros(2), np.full(2, EPU_PHI_MAX)
    sol = planning._solve_rollout(epu.params, np.asarray(EPU_STEPS[0]), np.zeros(2), lo, hi, 100)
    assert float(sol.residual_norm) <= planning.ROLLOUT_FTOL
    np.testing.assert_allclose(sol.x, [3.9751574, 2.5136546], rtol=1e-7)

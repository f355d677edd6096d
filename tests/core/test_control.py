"""Control laws (planning_and_control.md §3): each law against a hand computation of the spec
formulas, saturation, integrator behaviour, options, gain validation, and the §3.8 EE-integral
extension in a closed loop with a mismatched plant."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from hsa_core.controller import control
from hsa_core.controller.control import (
    CollocatedGains,
    Controller,
    EeIntegralGains,
    PidGains,
    default_gains,
)
from hsa_core.model import dynamics, kinematics, simulation
from hsa_core.model.params import load_params
from hsa_core.task import planning
from hsa_core.task.planning import Setpoint

DT = 0.025
# FPU worked example of planning_and_control.md §2.2, exact model (the spec's numbers, not planner
# output).
SETPOINT = Setpoint(
    chiee_des=np.array([0.00479247, 0.12781018, -0.066980133]),
    q_des=np.array([-1.1352565, 0.0080816386, 0.30410104]),
    phi_ss=np.array([1.9846028, 1.6323408]),
    optimality_error=1e-17,
)
Q = SETPOINT.q_des + np.array([0.4, 0.003, -0.006])
Q_DOT = np.array([0.8, -0.02, 0.05])
CHIEE = np.array([0.0061, 0.1269, -0.083])
CHIEE_DOT = np.array([-0.004, 0.002, 0.03])

gravity_vector = jax.jit(dynamics.gravity_vector)
actuation_jacobian = jax.jit(dynamics.actuation_jacobian)
ee_pose = jax.jit(kinematics.end_effector_pose)


@pytest.fixture(scope="module")
def params():
    return load_params("fpu")


@pytest.fixture(scope="module")
def controllers(params):
    """One compiled controller per law with the paper's gains (compiled once for the module)."""
    return {kind: Controller(kind, params) for kind in ("psatid", "psatid_gc", "pid")}


def varphi_by_hand(p, q, phi):
    """Collocated coordinates by the formula of planning_and_control.md §3.2, NumPy, virtual-rod
    constants."""
    a = {
        k: np.asarray(getattr(p, k))
        for k in (
            "roff",
            "h",
            "S_a_hat",
            "C_eps",
            "C_S_a",
            "C_S_b",
            "C_S_sh",
            "kappa_b_eq",
            "sigma_sh_eq",
            "sigma_a_eq",
        )
    }
    kappa, sigma_sh, sigma_ax = np.asarray(p.xi_eq) + q
    l = float(p.l)
    s = sigma_ax + a["roff"] * kappa
    h = a["h"]
    v = (h / l) * (
        (a["S_a_hat"] * a["C_eps"] + 2.0 * a["C_S_a"] * a["C_eps"] * h * phi / l) * s
        - a["C_S_a"] * (s**2 / 2.0 - a["sigma_a_eq"] * s)
        - a["C_S_b"] * (kappa**2 / 2.0 - a["kappa_b_eq"] * kappa)
        - a["C_S_sh"] * (sigma_sh**2 / 2.0 - a["sigma_sh_eq"] * sigma_sh)
    )
    return np.array([v[0], v[1], sigma_sh])


def J_h_by_hand(p, q, phi):
    """J_h: rows 1-2 are A^T(xi, phi), row 3 is [0, 1, 0] (§3.2)."""
    A = np.asarray(actuation_jacobian(p, q, phi))
    return np.vstack([A.T, [0.0, 1.0, 0.0]])


def psatid_by_hand(p, gains, sp, q, q_dot, e_int, gc=False):
    """phi^d and the next e_int of P-satI-D (§3.3), + GC (§3.4) if gc."""
    varphi, varphi_des = varphi_by_hand(p, q, sp.phi_ss), varphi_by_hand(p, sp.q_des, sp.phi_ss)
    J_h = J_h_by_hand(p, q, sp.phi_ss)
    e_y = varphi_des[:2] - varphi[:2]
    phi_des = sp.phi_ss + gains.kp * e_y - gains.kd * (J_h @ q_dot)[:2] + gains.ki * e_int
    if gc:
        G, G_des = np.asarray(gravity_vector(p, q)), np.asarray(gravity_vector(p, sp.q_des))
        phi_des += -np.linalg.solve(J_h.T, G_des)[:2] + np.linalg.solve(J_h.T, G)[:2]
    return phi_des, e_int + np.tanh(gains.gamma * e_y) * DT


@pytest.mark.parametrize("kind", ["psatid", "psatid_gc"])
def test_collocated_laws_match_hand_computation(params, controllers, kind):
    c = controllers[kind]
    c.reset()
    gains = CollocatedGains(0.3, 0.05, 0.02, 100.0)
    gc = kind == "psatid_gc"
    e_int = np.zeros(2)
    for q, q_dot in (
        (Q, Q_DOT),
        (Q + 0.1, -Q_DOT),
    ):  # the second tick uses the integral of the first
        expected, e_int_next = psatid_by_hand(params, gains, SETPOINT, q, q_dot, e_int, gc)
        phi, info = c.step(q, q_dot, CHIEE, CHIEE_DOT, SETPOINT)
        assert 0.0 < expected.min() and expected.max() < 3.4906585  # inside the limits: no clipping
        np.testing.assert_allclose(phi, expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(info.phi_des_unsat, expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(info.e_int, e_int_next, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(
            info.varphi, varphi_by_hand(params, q, SETPOINT.phi_ss), rtol=1e-12
        )
        np.testing.assert_allclose(
            info.varphi_des, varphi_by_hand(params, SETPOINT.q_des, SETPOINT.phi_ss), rtol=1e-12
        )
        assert info.saturated is False
        np.testing.assert_array_equal(info.phi_ss, SETPOINT.phi_ss)
        np.testing.assert_array_equal(info.q, q)
        np.testing.assert_array_equal(info.chiee_des, SETPOINT.chiee_des)
        assert np.all(np.isfinite(info.g_varphi)) == gc
        e_int = e_int_next


def test_gc_terms_published(params, controllers):
    c = controllers["psatid_gc"]
    c.reset()
    _, info = c.step(Q, Q_DOT, CHIEE, CHIEE_DOT, SETPOINT)
    J_h = J_h_by_hand(params, Q, SETPOINT.phi_ss)  # J_h at the current xi for both terms (§3.4)
    np.testing.assert_allclose(
        info.g_varphi, np.linalg.solve(J_h.T, gravity_vector(params, Q))[:2], rtol=1e-10
    )
    np.testing.assert_allclose(
        info.g_varphi_des,
        np.linalg.solve(J_h.T, gravity_vector(params, SETPOINT.q_des))[:2],
        rtol=1e-10,
    )


def test_task_space_pid_matches_hand_computation(controllers):
    c = controllers["pid"]
    c.reset()
    kp, ki, kd = 10.0, 110.0, 0.25
    e_int = np.zeros(2)
    for chiee, chiee_dot in ((CHIEE, CHIEE_DOT), (CHIEE + 0.0005, -CHIEE_DOT)):
        e = SETPOINT.chiee_des[:2] - chiee[:2]
        u = kp * e + ki * e_int - kd * chiee_dot[:2]
        half = np.radians(200.0) / 2.0  # phi_ss_PID = phi_max / 2 = 100 deg for the FPU (§3.5)
        expected = np.array([half + u[0] + u[1], half - u[0] + u[1]])
        phi, info = c.step(Q, Q_DOT, chiee, chiee_dot, SETPOINT)
        np.testing.assert_allclose(phi, expected, rtol=1e-12)
        np.testing.assert_allclose(info.e_int, e_int + e * DT, rtol=1e-12)
        np.testing.assert_allclose(info.phi_ss, [1.7453293, 1.7453293], rtol=1e-7)
        assert np.all(np.isnan(info.varphi))
        e_int = e_int + e * DT


@pytest.mark.parametrize("kind", ["psatid", "psatid_gc", "pid"])
def test_saturation_clips_to_limits(controllers, kind):
    c = controllers[kind]
    c.reset()
    # phi_ss close to the limit, measured axial strain 0.1 short, EE 60 mm off and moving away: phi1
    # exceeds phi_max.
    far = Setpoint(np.array([0.03, 0.135, -0.6]), SETPOINT.q_des, np.array([3.46, 0.02]), 0.0)
    q = SETPOINT.q_des - [0.0, 0.0, 0.1]
    phi, info = c.step(
        q, np.zeros(3), np.array([-0.03, 0.111, 0.5]), np.array([-8.0, 0.0, 0.0]), far
    )
    c.set_setpoint(SETPOINT)
    phi_max = np.radians(200.0)
    assert info.saturated is True
    np.testing.assert_array_equal(phi, np.clip(info.phi_des_unsat, 0.0, phi_max))
    assert np.any(info.phi_des_unsat > phi_max) or np.any(info.phi_des_unsat < 0.0)
    assert np.all((phi >= 0.0) & (phi <= phi_max))


def test_tanh_integrator_bounds_the_integral_rate(controllers):
    c = controllers["psatid"]
    c.reset()
    rng = np.random.default_rng(0)
    prev = np.zeros(2)
    for k in range(20):
        q = SETPOINT.q_des + rng.normal(scale=[3.0, 0.02, 0.05])
        _, info = c.step(q, rng.normal(size=3), CHIEE, CHIEE_DOT, SETPOINT)
        # K_i e_int changes by <= K_i dt per tick
        assert np.all(np.abs(info.e_int - prev) <= DT * (1.0 + 1e-12))
        prev = info.e_int
    # A large collocated error saturates the integrand: e_int grows by exactly dt per tick (to
    # rounding).
    c.reset()
    _, info = c.step(SETPOINT.q_des + [8.0, 0.0, 0.1], np.zeros(3), CHIEE, CHIEE_DOT, SETPOINT)
    np.testing.assert_allclose(np.abs(info.e_int), DT, rtol=1e-9)


def test_integral_reset_option(params, controllers):
    other = Setpoint(SETPOINT.chiee_des, SETPOINT.q_des, SETPOINT.phi_ss + 0.01, 0.0)
    keeping = controllers["psatid"]
    keeping.reset()
    keeping.step(Q, Q_DOT, CHIEE, CHIEE_DOT, SETPOINT)
    e_int = keeping.state.e_int
    assert np.all(e_int != 0.0)
    keeping.set_setpoint(other)  # default (paper): the integral is kept on a setpoint change
    np.testing.assert_array_equal(keeping.state.e_int, e_int)
    keeping.reset()
    np.testing.assert_array_equal(keeping.state.e_int, 0.0)

    resetting = Controller("psatid", params, reset_integral_on_setpoint_change=True)
    resetting.step(Q, Q_DOT, CHIEE, CHIEE_DOT, SETPOINT)
    assert np.all(resetting.state.e_int != 0.0)
    resetting.step(Q, Q_DOT, CHIEE, CHIEE_DOT, other)
    _, expected_e_int = psatid_by_hand(
        params, default_gains("psatid"), other, Q, Q_DOT, np.zeros(2)
    )
    np.testing.assert_allclose(resetting.state.e_int, expected_e_int, rtol=1e-12)


def test_gc_equals_psatid_without_gravity(params):
    weightless = params.replace(g=np.zeros(2))
    plain, gc = Controller("psatid", weightless), Controller("psatid_gc", weightless)
    for q, q_dot in ((Q, Q_DOT), (Q - 0.2, 2.0 * Q_DOT)):
        phi_plain, _ = plain.step(q, q_dot, CHIEE, CHIEE_DOT, SETPOINT)
        phi_gc, info = gc.step(q, q_dot, CHIEE, CHIEE_DOT, SETPOINT)
        np.testing.assert_allclose(phi_gc, phi_plain, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(info.g_varphi, 0.0)


def test_pure_law_is_functional(params):
    ref = control.make_reference(params, SETPOINT)
    meas = control.Measurement(*(jax.numpy.asarray(v) for v in (Q, Q_DOT, CHIEE, CHIEE_DOT)))
    state = control.initial_state()
    phi1, s1, _ = control.p_sati_d(params, default_gains("psatid"), ref, state, meas, DT)
    phi2, s2, _ = control.p_sati_d(params, default_gains("psatid"), ref, state, meas, DT)
    phi3, _, _ = control.p_sati_d(params, default_gains("psatid"), ref, s1, meas, DT)
    np.testing.assert_array_equal(phi1, phi2)
    np.testing.assert_array_equal(s1.e_int, s2.e_int)
    np.testing.assert_allclose(
        np.asarray(phi3) - np.asarray(phi1), 0.05 * np.asarray(s1.e_int), rtol=1e-9
    )


def test_paper_default_gains():
    for material in ("fpu", "epu"):
        assert control.default_gains("psatid", material) == CollocatedGains(
            kp=0.3, ki=0.05, kd=0.02, gamma=100.0
        )
        assert control.default_gains("psatid_gc", material) == CollocatedGains(
            kp=0.3, ki=0.05, kd=0.02, gamma=100.0
        )
        assert control.default_gains("pid", material) == PidGains(kp=10.0, ki=110.0, kd=0.25)


@pytest.mark.parametrize(
    ("kind", "gains", "name"),
    [
        ("psatid", dataclasses.replace(default_gains("psatid"), kp=-0.3), "kp"),
        ("psatid", dataclasses.replace(default_gains("psatid"), ki=float("nan")), "ki"),
        ("psatid_gc", dataclasses.replace(default_gains("psatid_gc"), gamma=0.0), "gamma"),
        ("pid", dataclasses.replace(default_gains("pid"), kd=float("inf")), "kd"),
        ("pid", default_gains("psatid"), "PidGains"),
    ],
)
def test_gain_validation_names_the_gain(params, kind, gains, name):
    with pytest.raises(ValueError, match=name):
        Controller(kind, params, gains)


def test_invalid_configuration_and_setpoints(params, controllers):
    with pytest.raises(ValueError, match="z_max"):
        Controller("psatid", params, ee_integral=EeIntegralGains(z_max=-1.0))
    with pytest.raises(ValueError, match="collocated"):
        Controller("pid", params, ee_integral=EeIntegralGains())
    with pytest.raises(ValueError, match="dt"):
        Controller("pid", params, dt=0.0)
    with pytest.raises(ValueError):
        Controller("lqr", params)
    fresh = Controller("pid", params)
    with pytest.raises(RuntimeError, match="setpoint"):
        fresh.step(Q, Q_DOT, CHIEE, CHIEE_DOT)
    c = controllers["psatid"]
    for bad, why in (
        (Setpoint(SETPOINT.chiee_des, SETPOINT.q_des, SETPOINT.phi_ss, 2e-3), "optimality"),
        (Setpoint(SETPOINT.chiee_des, SETPOINT.q_des, np.array([-0.1, 1.0]), 0.0), "phi_ss"),
        (Setpoint(SETPOINT.chiee_des, SETPOINT.q_des, np.array([1.0, 3.6]), 0.0), "phi_ss"),
        (
            Setpoint(SETPOINT.chiee_des, np.array([np.nan, 0.0, 0.3]), SETPOINT.phi_ss, 0.0),
            "non-finite",
        ),
    ):
        with pytest.raises(ValueError, match=why):
            c.set_setpoint(bad)
        assert c.setpoint is not bad


@pytest.mark.parametrize("kind", ["psatid", "psatid_gc", "pid"])
def test_non_finite_measurements_are_refused_without_touching_the_integrators(params, kind):
    c = Controller(kind, params, ee_integral=EeIntegralGains() if kind != "pid" else None)
    c.set_setpoint(SETPOINT)
    c.step(Q, Q_DOT, CHIEE, CHIEE_DOT)
    before = c.state
    for bad in (np.nan, np.inf):
        for which in range(4):
            args = [np.array(v, dtype=float) for v in (Q, Q_DOT, CHIEE, CHIEE_DOT)]
            args[which][1] = bad
            with pytest.raises(ValueError, match="non-finite"):
                c.step(*args)
    after = c.state
    assert np.array_equal(before.e_int, after.e_int) and np.array_equal(before.z_ee, after.z_ee)


def test_steady_state_sensitivity_matches_finite_differences(params):
    """S_ss of §3.8 (implicit-function theorem) equals central differences of p_ee(q_eq(phi))."""
    S_ss, _ = control.ee_integral_maps(params, SETPOINT.q_des, SETPOINT.phi_ss)
    delta = 1e-5
    columns = []
    for j in range(2):
        step = np.zeros(2)
        step[j] = delta
        p = [
            ee_pose(
                params, planning.static_equilibrium(params, SETPOINT.phi_ss + s, SETPOINT.q_des)[0]
            )[:2]
            for s in (step, -step)
        ]
        columns.append((np.asarray(p[0]) - np.asarray(p[1])) / (2.0 * delta))
    np.testing.assert_allclose(S_ss, np.stack(columns, axis=1), rtol=1e-6, atol=1e-9)


def closed_loop_ee_error(plant, controller, setpoint, duration):
    """Run the controller at 40 Hz against the plant (RK4, dt = 2.5 ms, stable below 3.8 ms); EE
    errors [m] per tick."""
    substeps = 10
    plant_step = jax.jit(
        lambda x, phi: simulation.simulate(plant, x, phi[None, :], DT / substeps, substeps)[-1]
    )
    fk = jax.jit(
        lambda x: (
            kinematics.end_effector_pose(plant, x[:3]),
            kinematics.end_effector_jacobian(plant, x[:3]) @ x[3:],
        )
    )
    x = np.zeros(6)
    errors = []
    for _ in range(int(round(duration / DT))):
        chiee, chiee_dot = (np.asarray(v) for v in fk(x))
        phi, _ = controller.step(x[:3], x[3:], chiee, chiee_dot, setpoint)
        x = np.asarray(plant_step(x, phi))
        errors.append(np.linalg.norm(setpoint.chiee_des[:2] - chiee[:2]))
    return np.array(errors)


def test_ee_integral_removes_steady_state_error_under_model_mismatch(params):
    """Plant shear stiffness half the model's (the CS model captures shear poorly, experiments.md
    §6): P-satI-D keeps an EE offset (its integral acts on varphi, which does not contain the
    shear); the §3.8 extension removes it."""
    plant = params.replace(S_sh_hat=0.5 * np.asarray(params.S_sh_hat))
    setpoint = SETPOINT
    plain = closed_loop_ee_error(plant, Controller("psatid", params), setpoint, 6.0)
    extended = closed_loop_ee_error(
        plant, Controller("psatid", params, ee_integral=EeIntegralGains()), setpoint, 8.0
    )
    # settled, with an offset > 0.4 mm
    assert np.ptp(plain[-40:]) < 1e-6 and np.mean(plain[-40:]) > 0.4e-3
    assert np.max(extended[-40:]) < 0.2e-3

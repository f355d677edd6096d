"""RK4 simulator: zero-order hold, steady states (S1), energy balance, convergence order (model.md
§7.1, §9.4, §10)."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_core.model import dynamics as dyn
from hsa_core.model import simulation as sim
from hsa_core.model.params import HsaParams
from tests.core.conftest import assert_printed, params_for


@pytest.mark.parametrize(
    "kappa_rule, q_expected, chiee_expected",
    [
        ("exact", [3.3248719, -0.023905921, 0.41951499], [-0.014657464, 0.13357871, 0.19616744]),
        (
            "exp2023_shift",
            [3.3148719, -0.023905921, 0.41951499],
            [-0.014618005, 0.13358532, 0.1955775],
        ),
    ],
)
def test_S1_steady_state(model, kappa_rule: str, q_expected, chiee_expected) -> None:
    """model.md §10 S1: FPU, phi = [2, 3] held from rest, RK4 dt = 5e-4 for 5 s."""
    p = params_for("fpu", kappa_rule)
    phi = jnp.array([2.0, 3.0])
    x = np.asarray(model.rollout(p, phi, duration=5.0, dt=5e-4))
    assert np.abs(x[3:]).max() < 1e-12
    assert_printed(x[:3], q_expected, rtol=1e-7, name="q")
    assert_printed(model.fk(p, jnp.asarray(x[:3])), chiee_expected, rtol=1e-7, name="chiee")
    # the static root
    assert np.abs(np.asarray(model.residual(p, jnp.asarray(x[:3]), phi))).max() < 1e-10


def test_rollouts_settle_cleanly_near_zero_curvature(model) -> None:
    """model.md §9.4: with the exact model, a symmetric twist settles at kappa = 0 without
    chattering."""
    p = params_for("epu")
    x = np.asarray(model.rollout(p, jnp.array([1.5, 1.5]), duration=5.0, dt=5e-4))
    assert abs(x[0]) < 1e-12 and np.abs(x[3:]).max() < 1e-11


@pytest.mark.parametrize("material, y_rest", [("fpu", 0.11014), ("epu", 0.11125)])
def test_rest_pose_by_rollout(model, material: str, y_rest: float) -> None:
    p = params_for(material)
    x = model.rollout(p, jnp.zeros(2), duration=5.0, dt=5e-4)
    assert float(model.fk(p, x[:3])[1]) == pytest.approx(y_rest, abs=5e-6)


_simulate = jax.jit(sim.simulate, static_argnames=("substeps",))
N_HOLD, SUBSTEPS = 100, 50  # one compiled rollout shape shared by the tests below


def _rollout(params: HsaParams, x0, phi_seq, dt: float) -> jnp.ndarray:
    """N_HOLD samples of phi, each held for SUBSTEPS RK4 steps of dt."""
    return _simulate(
        params,
        jnp.asarray(x0),
        jnp.broadcast_to(jnp.asarray(phi_seq), (N_HOLD, 2)),
        dt,
        substeps=SUBSTEPS,
    )


def test_simulate_is_a_zero_order_hold_of_rk4_steps(fpu: HsaParams, model) -> None:
    rng = np.random.default_rng(0)
    phi_seq = jnp.asarray(rng.uniform(0.0, 3.0, size=(N_HOLD, 2)))
    x0 = jnp.array([0.5, 0.01, 0.05, 0.0, 0.0, 0.0])
    xs = _rollout(fpu, x0, phi_seq, 2e-4)
    assert xs.shape == (N_HOLD + 1, 6)
    np.testing.assert_array_equal(xs[0], x0)
    x = x0
    for k in range(2):
        for _ in range(SUBSTEPS):
            x = model.rk4(fpu, x, phi_seq[k], 2e-4)
        np.testing.assert_allclose(xs[k + 1], x, rtol=1e-13, atol=1e-16)
    # defaults: one input sample per 25 ms control period
    assert sim.DEFAULT_DT * sim.DEFAULT_SUBSTEPS == pytest.approx(0.025, rel=1e-15)
    assert sim.DEFAULT_DT < 3.8e-3  # RK4 stability limit for |lambda|max ~ 730 1/s (model.md §9.4)


def test_rk4_has_fourth_order_convergence(fpu: HsaParams) -> None:
    phi = jnp.array([1.0, 2.5])
    x0 = jnp.array([2.0, 0.01, 0.1, 0.0, 0.0, 0.0])
    # the state at t = 0.1 s: row 0.1 / (SUBSTEPS dt) of each rollout
    at = {
        dt: np.asarray(_rollout(fpu, x0, phi, dt))[round(0.1 / (SUBSTEPS * dt))]
        for dt in (4e-4, 2e-4, 2.5e-5)
    }
    errs = [np.abs(at[dt] - at[2.5e-5]).max() for dt in (4e-4, 2e-4)]
    assert 2**4 * 0.7 < errs[0] / errs[1] < 2**4 * 1.3, errs


@jax.jit
@partial(jax.vmap, in_axes=(None, 0))
def _energy(params: HsaParams, x: jnp.ndarray) -> jnp.ndarray:
    """Total mechanical energy at phi = 0: kinetic + gravity + elastic potential (states
    batched)."""
    q, q_dot = x[:3], x[3:]
    return (
        dyn.kinetic_energy(params, q, q_dot)
        + dyn.gravitational_potential(params, q)
        + dyn.elastic_potential(params, q)
    )


@pytest.mark.parametrize("payload", [0.0, 0.2])
def test_energy_is_conserved_without_damping_and_dissipated_with_it(
    fpu: HsaParams, payload: float
) -> None:
    p = fpu.replace(m_pl=payload, CoG_pl=[0.003, -0.0255], chiee_off=[0.0, 0.025, 0.0])
    undamped = p.replace(zeta_b=[0.0, 0.0], zeta_sh=[0.0, 0.0], zeta_a=[0.0, 0.0])
    # far from equilibrium, crossing kappa = 0 repeatedly
    x0 = jnp.array([12.0, 0.02, 0.15, 30.0, -0.5, 1.0])
    xs = _rollout(undamped, x0, jnp.zeros(2), 1e-4)  # 0.5 s
    assert np.any(np.asarray(xs[:, 0]) < 0.0) and np.any(np.asarray(xs[:, 0]) > 0.0)
    E = np.asarray(_energy(p, xs))
    swing = np.abs(
        np.asarray(_energy(p, xs.at[:, 3:].set(0.0))) - E
    ).max()  # energy exchanged between kinetic and potential
    # RK4 at dt = 1e-4 s: drift below 1e-6 of the exchanged energy over 0.5 s
    assert np.abs(E - E[0]).max() < 1e-6 * swing, (np.abs(E - E[0]).max(), swing)
    # with damping the energy never increases (q_dot^T D q_dot >= 0), up to the same integration
    # error
    E = np.asarray(_energy(p, _rollout(p, x0, jnp.zeros(2), 1e-4)))
    assert np.all(np.diff(E) <= 1e-6 * swing) and E[-1] < E[0] - 0.5 * swing


def test_simulate_vmaps_over_initial_states(fpu: HsaParams) -> None:
    x0 = jnp.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [3.0, 0.01, 0.2, 0.0, 0.0, 0.0]])
    phi_seq = jnp.full((4, 2), 1.5)
    batched = jax.jit(jax.vmap(partial(sim.simulate, substeps=5), in_axes=(None, 0, None, None)))(
        fpu, x0, phi_seq, 2e-3
    )
    for i in range(2):
        np.testing.assert_allclose(
            batched[i], _simulate(fpu, x0[i], phi_seq, 2e-3, substeps=5), rtol=1e-13, atol=1e-16
        )

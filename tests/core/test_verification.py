"""Model verification by replay (identification.md §6): the Dopri5 integrator, zero error against
the model itself, the expected and ordered error against perturbed plants, and the time-lag
estimate.

Ground truth by construction: "measured" records are rollouts of hsa_core.model.simulation.simulate
(RK4, another integrator) of a known plant under a seeded GBN; the expected replay error against a
perturbed plant is computed here from two such rollouts, not by the verification code.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hsa_core.model import kinematics, simulation
from hsa_core.model.params import load_params
from hsa_core.sysid import excitation, verification
from hsa_core.task import planning

DT_MOCAP = 0.005
DURATION = 2.0
SUB = 20  # RK4 steps per mocap period for the "measurements" (0.25 ms)


@pytest.fixture(scope="module")
def model():
    return load_params("fpu")


@pytest.fixture(scope="module")
def phi(model):
    """A GBN (settling time 0.5 s, both rods) resampled to the 200 Hz mocap grid."""
    exc = excitation.gbn(float(model.phi_max[0]), DURATION, seed=5, mode="combined")
    grid = np.arange(int(round(DURATION / DT_MOCAP))) * DT_MOCAP
    return grid, excitation.zero_order_hold(exc.t, exc.phi, grid)


def record(plant, phi_grid):
    """Measured poses (N, 3) and configurations (N, 3, relative to the plant's rest strains) of the
    plant from rest."""
    q0, _ = planning.static_equilibrium(plant, np.zeros(2), np.zeros(3))
    xs = np.asarray(
        simulation.simulate(
            plant, jnp.concatenate([q0, jnp.zeros(3)]), phi_grid[:-1], DT_MOCAP / SUB, SUB
        )
    )
    chiee = np.asarray(jax.vmap(lambda q: kinematics.end_effector_pose(plant, q))(xs[:, :3]))
    return chiee, xs[:, :3]


def test_dopri5_is_fifth_order():
    """Global error of x' = A x over 1 s drops by ~2^5 when the step halves."""
    A = jnp.array([[0.0, 1.0], [-4.0, -0.4]])
    x0 = jnp.array([1.0, 0.0])
    exact = np.asarray(jax.scipy.linalg.expm(A) @ x0)
    step = jax.jit(lambda x, h: verification.dopri5_step(lambda s: A @ s, x, h))
    errors = []
    for n in (10, 20, 40):
        x = x0
        for _ in range(n):
            x = step(x, 1.0 / n)
        errors.append(np.linalg.norm(np.asarray(x) - exact))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 25) & (ratios < 40)), ratios


def test_model_against_itself_has_zero_error(model, phi):
    grid, phi_grid = phi
    chiee, q = record(model, phi_grid)
    res = verification.verify(model, grid, chiee, phi_grid)
    assert res.lag == 0.0
    # only the integrators differ (RK4 at 0.25 ms vs Dopri5 at 0.1 ms): 0.1 um, 1000x below the
    # mocap noise
    assert res.rmse["x"] < 1e-7 and res.rmse["y"] < 1e-7
    assert all(res.nrmse[c] < 1e-5 for c in verification.CHANNELS), res.nrmse
    # IK of the poses = the plant's q
    np.testing.assert_allclose(res.measured[:, 3:], q, rtol=0, atol=1e-12)
    # the GBN excites the workspace (so the zero error means something)
    assert np.ptp(res.measured[:, 0]) > 0.02


def test_perturbed_plants_give_the_expected_ordered_error(model, phi):
    grid, phi_grid = phi
    chiee_model, q_model = record(model, phi_grid)
    rmse = []
    for factor in (1.02, 1.05, 1.10):
        plant = model.replace(
            S_a_hat=np.asarray(model.S_a_hat) * factor,
            S_b_hat=np.asarray(model.S_b_hat) * factor,
            C_eps=np.asarray(model.C_eps) / factor,
        )
        chiee, _ = record(plant, phi_grid)
        res = verification.verify(model, grid, chiee, phi_grid, max_lag=0.0)
        expected_x = np.sqrt(np.mean((chiee_model[:, 0] - chiee[:, 0]) ** 2))
        expected_y = np.sqrt(np.mean((chiee_model[:, 1] - chiee[:, 1]) ** 2))
        # the replay starts from the IK of the plant's first pose (its rest), not from the model's
        # rest: a small initial transient, so agreement within 3 % rather than exactly
        assert res.rmse["x"] == pytest.approx(expected_x, rel=0.03)
        assert res.rmse["y"] == pytest.approx(expected_y, rel=0.03)
        rmse.append([res.rmse[c] for c in verification.CHANNELS])
    rmse = np.array(rmse)
    # larger mismatch, larger error everywhere
    assert np.all(rmse[0] > 0.0) and np.all(np.diff(rmse, axis=0) > 0.0)


def test_a_delayed_input_shows_as_lag(model, phi):
    grid, phi_grid = phi
    chiee, _ = record(model, phi_grid)
    # the replay input lags by 20 ms
    delayed = np.concatenate([np.repeat(phi_grid[:1], 4, axis=0), phi_grid[:-4]])
    res = verification.verify(model, grid, chiee, delayed, max_lag=0.05)
    assert res.lag == pytest.approx(0.020, abs=1e-12)
    assert res.rmse_lagged["x"] < 0.05 * res.rmse["x"]


def test_report_table_and_figure(model, phi, tmp_path):
    grid, phi_grid = phi
    chiee, _ = record(model, phi_grid)
    res = verification.verify(model, grid, chiee, phi_grid)
    table = verification.format_table({"gbn_self": res})
    assert "gbn_self" in table and "kappa_be" in table
    assert verification.plot(res, tmp_path / "v.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="increasing"):
        verification.verify(model, grid[::-1], chiee, phi_grid)

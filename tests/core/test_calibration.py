"""Rest-strain calibration (planning_and_control.md §6.5): a simulated rest with known sigma_a_eq is
recovered; windows that are not a rest at phi = 0 are refused.

Ground truth by construction: the rest poses come from the static equilibrium of a plant whose
sigma_a_eq is set (hsa_core.task.planning.static_equilibrium, an iterative solve of G + K - alpha =
0), or from a dynamic rollout; the calibration only sees the poses and a model with another
(nominal) sigma_a_eq.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from hsa_core.model import kinematics, simulation
from hsa_core.model.params import load_params
from hsa_core.sysid import calibration
from hsa_core.task import planning

NOISE = np.array([1e-4, 1e-4, 1e-3])  # mocap noise, m, m, rad (hsa_core.sim.disturbance default)
fk = jax.jit(kinematics.end_effector_pose)


def rest_pose(plant) -> np.ndarray:
    """EE pose of the plant hanging at phi = 0."""
    q, res = planning.static_equilibrium(plant, np.zeros(2), np.zeros(3))
    assert float(res) < 1e-10
    return np.asarray(fk(plant, q))


@pytest.mark.parametrize("material, truth", [("fpu", [1.03, 0.98]), ("epu", [1.055, 1.045])])
def test_noise_free_rest_recovers_the_set_rest_strains(material, truth):
    nominal = load_params(material)  # sigma_a_eq = 1 in the packaged sets
    pose = rest_pose(nominal.replace(sigma_a_eq=np.array(truth)))
    result = calibration.calibrate(nominal, np.tile(pose, (20, 1)))
    np.testing.assert_allclose(result.sigma_a_eq, truth, rtol=0, atol=1e-10)
    assert result.samples_used == 20 and result.residual_rms < 1e-10
    assert np.all(result.sigma_a_eq_std < 1e-10)


def test_result_does_not_depend_on_the_reference_rest_strains_of_the_model():
    nominal = load_params("fpu")
    pose = rest_pose(nominal.replace(sigma_a_eq=np.array([1.01, 0.97])))
    a = calibration.calibrate(nominal, np.tile(pose, (5, 1))).sigma_a_eq
    b = calibration.calibrate(
        nominal.replace(sigma_a_eq=np.array([0.8, 1.3])), np.tile(pose, (5, 1))
    ).sigma_a_eq
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_noisy_rest_is_recovered_within_its_reported_uncertainty():
    """200 samples with 0.1 mm / 1 mrad noise: |error| <= 4 sigma for 10 seeds, sigma below 5e-4
    (0.03 mm of rod)."""
    nominal = load_params("fpu")
    truth = np.array([1.02, 0.99])
    pose = rest_pose(nominal.replace(sigma_a_eq=truth))
    z = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        result = calibration.calibrate(nominal, pose + rng.normal(size=(200, 3)) * NOISE)
        assert np.all(result.sigma_a_eq_std < 5e-4)
        z.append((result.sigma_a_eq - truth) / result.sigma_a_eq_std)
        assert np.all(np.abs(result.sigma_a_eq - truth) < 1e-3)
    z = np.array(z)
    assert np.all(np.abs(z) < 4.0)
    # the reported sigma is the right size, not just large
    assert 0.3 < np.sqrt(np.mean(z**2)) < 2.0


def test_rest_check_accepts_a_noisy_rest_and_refuses_twist_motion_and_short_windows():
    nominal = load_params("fpu")
    plant = nominal.replace(sigma_a_eq=np.array([1.02, 0.99]))
    pose = rest_pose(plant)
    rng = np.random.default_rng(0)
    t = np.arange(200) / 200.0
    noisy = pose + rng.normal(size=(200, 3)) * NOISE
    assert calibration.rest_problem(t, noisy, np.zeros((50, 2))) is None
    assert "phi != 0" in calibration.rest_problem(t, noisy, np.tile([0.0, 0.05], (50, 1)))
    assert "no actuation" in calibration.rest_problem(t, noisy, np.zeros((0, 2)))
    assert "not enough samples" in calibration.rest_problem(t[:3], noisy[:3], np.zeros((1, 2)))

    # the first second after a 1 rad elongation step, simulated at 200 Hz: the robot moves
    q0, _ = planning.static_equilibrium(plant, np.zeros(2), np.zeros(3))
    xs = simulation.simulate(
        plant, np.concatenate([q0, np.zeros(3)]), np.tile([1.0, 1.0], (200, 1)), 1.25e-3, 4
    )
    moving = np.asarray(jax.vmap(lambda q: fk(plant, q))(xs[1:, :3]))
    assert "moving" in calibration.rest_problem(t, moving, np.zeros((50, 2)))
    # a slow drift of 5 mm/s within the spread bound is refused as drifting
    drift = pose + np.outer(t * 0.1, [0.005, 0.0, 0.0])
    assert "drifting" in calibration.rest_problem(t * 0.1, drift, np.zeros((5, 2)))

"""Marker geometry (hsa_core.model.visual): polylines against the model's kinematics (model.md
§6.1–6.2) and against closed forms written out here (the circular-arc backbone of §6.1, rod offsets
of §6.2, arc lengths from the strains)."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

from hsa_core.model import kinematics as kin
from hsa_core.model import visual
from hsa_core.model.params import HsaParams, load_params

N = 16
GEOMETRY = jax.jit(visual.robot_geometry, static_argnames="n_points")
FK = jax.jit(kin.end_effector_pose)


def random_configurations(seed: int = 5) -> list[np.ndarray]:
    """Random q over the workspace plus straight and nearly straight ones (κ = 0, ±1e-9, 1e-4, −0.05
    1/m)."""
    rng = np.random.default_rng(seed)
    qs = [
        np.array([rng.uniform(-20, 20), rng.uniform(-0.05, 0.05), rng.uniform(-0.1, 0.6)])
        for _ in range(12)
    ]
    for kappa in (0.0, 1e-9, -1e-9, 1e-4, -0.05):
        qs.append(np.array([kappa, rng.uniform(-0.05, 0.05), rng.uniform(-0.1, 0.6)]))
    return qs


QS = random_configurations()


@pytest.fixture(scope="module", params=["fpu", "epu_offset"])
def params(request) -> HsaParams:
    """FPU set, and the EPU set with a 3-D-printed EE offset and an angle offset (model.md §5.1)."""
    if request.param == "fpu":
        return load_params("fpu")
    return load_params("epu").replace(chiee_off=np.array([0.004, 0.025, 0.1]))


def rotation(theta: float) -> np.ndarray:
    """R(θ) (model.md §4)."""
    return np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])


def backbone_closed_form(params: HsaParams, xi: np.ndarray, s: np.ndarray) -> np.ndarray:
    """p(s) of model.md §6.1: the κ ≠ 0 closed form, or the straight sheared line for |κ| < 1e-6
    (exact to ~1e-15 m)."""
    kappa, sh, ax = xi
    l_pc = float(params.l_pc)
    if abs(kappa) < 1e-6:
        return np.stack([sh * s + 0.0 * kappa, l_pc + ax * s], axis=-1)
    return np.stack(
        [
            (sh * np.sin(kappa * s) - ax * (1 - np.cos(kappa * s))) / kappa,
            l_pc + (sh * (1 - np.cos(kappa * s)) + ax * np.sin(kappa * s)) / kappa,
        ],
        axis=-1,
    )


def polyline_length(points: np.ndarray) -> float:
    """Sum of the segment lengths."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=-1).sum())


@pytest.mark.parametrize("q", QS, ids=lambda q: f"k{q[0]:.3g}")
def test_backbone_follows_the_model_and_ends_at_the_fk_end_effector(
    params: HsaParams, q: np.ndarray
) -> None:
    g = GEOMETRY(params, q, n_points=N)
    xi = np.asarray(params.xi_eq) + q
    l, l_pc, l_dc, h_p = (
        float(v) for v in (params.l, params.l_pc, params.l_dc, params.platform_size[1])
    )
    backbone = np.asarray(g.backbone)
    assert backbone.shape == (N + 3, 2)
    # base origin (top of the motor plate)
    np.testing.assert_allclose(backbone[0], [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(backbone[1], [0.0, l_pc], atol=1e-15)
    s = np.linspace(0.0, l, N)
    # closed forms lose digits to cancellation for small κ: 1e-11 m is far below anything visible
    np.testing.assert_allclose(backbone[1 : N + 1], backbone_closed_form(params, xi, s), atol=1e-11)
    theta = xi[0] * l
    chiee = np.asarray(FK(params, q))
    # the drawn EE is the FK end-effector
    np.testing.assert_allclose(backbone[-1], chiee[:2], atol=1e-14)
    np.testing.assert_allclose(np.asarray(g.end_effector), chiee, atol=1e-14)
    np.testing.assert_allclose(
        backbone[-2], backbone[N] + rotation(theta) @ [0.0, l_dc + h_p], atol=1e-14
    )
    np.testing.assert_allclose(
        np.asarray(g.platform_pose),
        [*(backbone[N] + rotation(theta) @ [0.0, l_dc + h_p / 2]), theta],
        atol=1e-14,
    )
    np.testing.assert_allclose(
        np.asarray(g.platform_orientation),
        [0, 0, math.sin(theta / 2), math.cos(theta / 2)],
        atol=1e-15,
    )
    tip = np.asarray(kin.backbone_pose(params, q, l))
    np.testing.assert_allclose(backbone[N], tip[:2], atol=1e-14)


@pytest.mark.parametrize("q", QS, ids=lambda q: f"k{q[0]:.3g}")
def test_rods_sit_at_their_offsets_with_the_lengths_their_strains_imply(
    params: HsaParams, q: np.ndarray
) -> None:
    g = GEOMETRY(params, q, n_points=N)
    xi = np.asarray(params.xi_eq) + q
    kappa, sh, ax = xi
    l, l_pc, l_dc = float(params.l), float(params.l_pc), float(params.l_dc)
    backbone, rods = np.asarray(g.backbone), np.asarray(g.rods)
    assert rods.shape == (2, N + 2, 2)
    s = np.linspace(0.0, l, N)
    # circular arc sampled at equal turning angles Δ: each chord is (segment arc
    # length)·sin(Δ/2)/(Δ/2)
    half = kappa * l / (N - 1) / 2
    chord_factor = math.sin(half) / half if half != 0.0 else 1.0
    for i, roff in enumerate(np.asarray(params.roff)):
        # proximal cap on the motor plate
        np.testing.assert_allclose(rods[i, 0], [roff, 0.0], atol=1e-15)
        np.testing.assert_allclose(rods[i, 1], [roff, l_pc], atol=1e-15)
        for k in range(N):  # centreline = backbone + R(κ s) [roff, 0] (model.md §6.2)
            local = rotation(-kappa * s[k]) @ (rods[i, k + 1] - backbone[k + 1])
            np.testing.assert_allclose(local, [roff, 0.0], atol=1e-14)
        # rod axial strain (model.md §6.4); speed |dp_i/ds| = |[σ_sh, σ_a,i]|
        axial = ax + roff * kappa
        np.testing.assert_allclose(
            polyline_length(rods[i, 1 : N + 1]),
            l * math.hypot(sh, axial) * chord_factor,
            rtol=1e-11,
        )
        # distal cap
        np.testing.assert_allclose(np.linalg.norm(rods[i, -1] - rods[i, -2]), l_dc, rtol=1e-12)
        np.testing.assert_allclose(
            rods[i, -1] - rods[i, -2], rotation(kappa * l) @ [0.0, l_dc], atol=1e-15
        )
        np.testing.assert_allclose(np.linalg.norm(rods[i, 1] - rods[i, 0]), l_pc, rtol=1e-12)
    np.testing.assert_allclose(
        polyline_length(backbone[1 : N + 1]), l * math.hypot(sh, ax) * chord_factor, rtol=1e-11
    )
    np.testing.assert_allclose(np.asarray(kin.rod_positions(params, q, l)), rods[:, N], atol=1e-14)


@pytest.mark.parametrize("q", QS[:4] + QS[-5:], ids=lambda q: f"k{q[0]:.3g}")
def test_platform_outline_is_the_plate_on_the_distal_caps(params: HsaParams, q: np.ndarray) -> None:
    g = GEOMETRY(params, q, n_points=N)
    w, h_p = float(params.platform_size[0]), float(params.platform_size[1])
    outline, rods = np.asarray(g.platform), np.asarray(g.rods)
    x, y, theta = np.asarray(g.platform_pose)
    assert outline.shape == (5, 2)
    np.testing.assert_array_equal(outline[0], outline[-1])  # closed
    np.testing.assert_allclose(
        np.linalg.norm(np.diff(outline, axis=0), axis=-1), [w, h_p, w, h_p], rtol=1e-12
    )
    local = (outline[:4] - [x, y]) @ rotation(theta)  # rows: R(θ)ᵀ (corner − centre)
    np.testing.assert_allclose(np.abs(local), [[w / 2, h_p / 2]] * 4, atol=1e-15)
    for i in range(
        2
    ):  # the distal caps end on the top edge of the plate (local y = −h_p/2 from the centre)
        cap_end = rotation(theta).T @ (rods[i, -1] - [x, y])
        np.testing.assert_allclose(cap_end, [float(params.roff[i]), -h_p / 2], atol=1e-15)


def test_compiles_vectorises_and_refuses_too_few_points() -> None:
    params = load_params("fpu")
    qs = np.stack(QS)
    batched = jax.jit(jax.vmap(visual.robot_geometry, in_axes=(None, 0)))(params, qs)
    compiled = visual.geometry_fn(params, 8)
    for j in (0, 5, len(QS) - 1):
        for a, b in zip(compiled(qs[j]), visual.robot_geometry(params, qs[j], n_points=8)):
            np.testing.assert_allclose(a, b, atol=1e-15)
        for a, b in zip((field[j] for field in batched), visual.robot_geometry(params, qs[j])):
            np.testing.assert_allclose(a, b, atol=1e-15)
    assert np.asarray(compiled(qs[0]).backbone).shape == (11, 2)
    with pytest.raises(ValueError, match="n_points"):
        visual.robot_geometry(params, qs[0], n_points=1)


@pytest.mark.parametrize("theta", [0.0, 0.7, -1.2, math.pi])
def test_planar_quaternion_rotates_about_z0(theta: float) -> None:
    x, y, z, w = np.asarray(visual.planar_quaternion(theta))
    assert math.isclose(x * x + y * y + z * z + w * w, 1.0, rel_tol=1e-15) and x == y == 0.0
    # rotation matrix of a unit quaternion, first column: the image of x₀
    first_column = [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)]
    np.testing.assert_allclose(first_column, [math.cos(theta), math.sin(theta), 0.0], atol=1e-15)

"""Tests of hsa_core.sensing.mocap: world → {0} → SE(2) chain of spec §6.1–6.2, its inverse and the
validity checks."""

import math

import numpy as np
import pytest

from hsa_core.sensing.mocap import (
    MocapConfig,
    WorkspaceBox,
    jump_problem,
    matrix_to_quaternion,
    planar_to_world,
    pose_problem,
    quaternion_to_matrix,
    rest_pose_problem,
    world_to_planar,
)

BASE = np.array([0.31, 1.42, -0.27])  # measured base-marker position in the world (Y up)
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def quat_about_world_x(angle):
    """Quaternion (x, y, z, w) of a rotation by angle about the world x axis."""
    return np.array([math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)])


def test_spec_base_rotation_matrix():
    # spec §6.1: (−0.7071068, 0, 0, 0.7071068) is R_W0 = [[1, 0, 0], [0, 0, 1], [0, −1, 0]]
    np.testing.assert_allclose(
        quaternion_to_matrix([-0.7071068, 0, 0, 0.7071068]),
        [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
        atol=1e-7,
    )


def test_straight_robot_at_rest_maps_to_0_110_0():
    # Hand-built with the documented chain: R_W0 maps z₀ to world +Y, the base origin is 3.5 mm
    # along z₀ from the base markers, the EE is 0.110 m further along z₀ and the platform marker 7
    # mm beyond it; the body reads identity.
    platform = BASE + np.array([0.0, 0.0035 + 0.110 + 0.007, 0.0])
    chiee = world_to_planar(BASE, platform, IDENTITY)
    np.testing.assert_allclose(chiee, [0.0, 0.110, 0.0], atol=1e-9)
    assert rest_pose_problem(chiee) is None


def test_rotation_about_base_x_gives_documented_signs():
    # Platform rotated by a > 0 about base x (= world x here) and displaced along its own z axis by
    # L.
    a, length = 0.3, 0.12
    r_x = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    r_w0 = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])
    p_0 = r_x @ [0.0, 0.0, length]  # EE in the 3-D base frame
    marker_0 = p_0 + r_x @ [0.0, 0.0, 0.007]
    platform = BASE + r_w0 @ ([0.0, 0.0, 0.0035] + marker_0)
    quat = quat_about_world_x(a)  # R_W0 R_x(a) R_W0ᵀ is a rotation about world x, as R_W0 fixes x
    chiee = world_to_planar(BASE, platform, quat)
    np.testing.assert_allclose(chiee, [length * math.sin(a), length * math.cos(a), -a], atol=1e-9)
    assert chiee[0] > 0 and chiee[2] < 0  # model.md §3: bending towards +x comes with θ < 0


@pytest.mark.parametrize("chiee", [[0.0, 0.110, 0.0], [0.021, 0.125, -0.45], [-0.035, 0.122, 0.5]])
def test_planar_to_world_round_trip(chiee):
    position, quaternion = planar_to_world(chiee, BASE)
    assert np.linalg.norm(quaternion) == pytest.approx(1.0) and quaternion[3] >= 0
    np.testing.assert_allclose(world_to_planar(BASE, position, quaternion), chiee, atol=1e-12)


def test_planar_to_world_of_rest_pose_matches_hand_construction():
    position, quaternion = planar_to_world([0.0, 0.110, 0.0], BASE)
    np.testing.assert_allclose(position, BASE + [0.0, 0.1205, 0.0], atol=1e-9)
    np.testing.assert_allclose(quaternion, IDENTITY, atol=1e-9)


def test_measured_base_orientation_option():
    cfg = MocapConfig(use_base_orientation=True)
    # whole robot yawed by 0.2 rad about world Y
    tilt = np.array([0.0, math.sin(0.1), 0.0, math.cos(0.1)])
    chiee = [0.01, 0.12, -0.2]
    position, quaternion = planar_to_world(chiee, BASE, cfg, base_quaternion=tilt)
    back = world_to_planar(BASE, position, quaternion, cfg, base_quaternion=tilt)
    np.testing.assert_allclose(back, chiee, atol=1e-12)
    # ignoring the base orientation, the same measurement reads differently
    assert not np.allclose(world_to_planar(BASE, position, quaternion), chiee, atol=1e-4)
    # an untilted base (identity reading) reproduces the default chain
    np.testing.assert_allclose(
        world_to_planar(BASE, position, quaternion, cfg, base_quaternion=IDENTITY),
        world_to_planar(BASE, position, quaternion),
        atol=1e-12,
    )
    with pytest.raises(ValueError):
        world_to_planar(BASE, position, quaternion, cfg)


def test_configurable_offsets():
    cfg = MocapConfig(base_offset=(0.0, 0.0, 0.0), marker_offset=(0.0, 0.0, 0.0))
    platform = BASE + np.array([0.0, 0.13, 0.0])
    np.testing.assert_allclose(
        world_to_planar(BASE, platform, IDENTITY, cfg), [0.0, 0.13, 0.0], atol=1e-12
    )
    with pytest.raises(ValueError):
        MocapConfig(base_quaternion=(0.0, 0.0, 0.0, 2.0))


def test_quaternion_matrix_round_trip():
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(200, 4)):
        q /= np.linalg.norm(q)
        q = q if q[3] >= 0 else -q
        r = quaternion_to_matrix(q)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        np.testing.assert_allclose(matrix_to_quaternion(r), q, atol=1e-12)


def test_validity_helpers():
    assert pose_problem(BASE, IDENTITY) is None
    assert "non-finite" in pose_problem([np.nan, 0, 0], IDENTITY)
    assert "norm" in pose_problem(BASE, [0, 0, 0, 0.5])
    assert "shape" in pose_problem(BASE[:2], IDENTITY)
    assert jump_problem([0.0, 0.12, 0.0], [0.002, 0.12, 0.0], dt=0.005) is None  # 0.4 m/s
    assert "position jumped" in jump_problem([0.0, 0.12, 0.0], [0.01, 0.12, 0.0], dt=0.005)  # 2 m/s
    assert "angle jumped" in jump_problem([0.0, 0.12, 0.0], [0.0, 0.12, 0.2], dt=0.005)  # 40 rad/s
    box = WorkspaceBox()
    assert box.problem([0.0, 0.12, 0.1]) is None
    assert "y" in box.problem([0.0, 0.5, 0.0])
    assert "theta" in box.problem([0.0, 0.12, 2.0])
    # a flipped world axis is caught at start-up
    assert "rest pose" in rest_pose_problem([0.0, -0.110, 0.0])

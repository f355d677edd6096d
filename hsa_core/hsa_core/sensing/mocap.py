"""Motion-capture poses → planar EE pose χ_ee in {0} and back, plus validity checks (spec §6.1–6.2).

Chain (planning_and_control.md §6.1–6.2; quaternions are (x, y, z, w) and are normalised before
use):

* Base frame: R_W0 = R(q_base) with the configured q_base = (−0.7071068, 0, 0, 0.7071068) (−90°
  about x), origin o_W0 = t̄ + R_W0 · base_offset, t̄ the measured base-body position and
  base_offset = (0, 0, 3.5 mm) along z₀. The measured base orientation is ignored unless
  ``use_base_orientation``: then R_W0 = R_meas,base · R(q_base), which follows a tilt of the base
  body while keeping the same convention when the base is untilted (identity reading).
* A body with measured world pose (t_WB, R_WB) becomes T_0B = T_W0⁻¹ · T_WB · [[R(q_base), 0], [0,
  1]], i.e. R_0B = R_W0ᵀ R_WB R(q_base) and t_0B = R_W0ᵀ (t_WB − o_W0); the right factor re-aligns
  the body frame (created aligned with the world by Motive) with {0} when the robot is straight.
* Platform → planar pose: p = t_0B − R_0B · marker_offset (marker 7 mm beyond the platform surface
  along body z), a_x = atan2(R_0B[2,1], R_0B[2,2]) (extrinsic x-y-z Euler angle about x), χ_ee =
  [−p_y, p_z, −a_x]. So a straight robot at rest is χ_ee ≈ [0, 0.110, 0], and a rotation a_x > 0
  about base x gives θ < 0 and, for a bent robot, x > 0 (the sign convention of model.md §3: φ₁ > φ₂
  ⇒ x > 0, θ < 0). Validate on the real set-up.
* ``planar_to_world`` inverts the chain for a planar pose (R_0B = R_x(−θ), p = [0, −x, y]); the
  simulator uses it to synthesise mocap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

BASE_QUATERNION = (-0.7071068, 0.0, 0.0, 0.7071068)
BASE_OFFSET = (0.0, 0.0, 0.0035)  # m, in {0}
MARKER_OFFSET = (0.0, 0.0, 0.007)  # m, in the platform body frame
REST_POSE = (0.0, 0.110, 0.0)  # χ_ee of the straight robot at rest (model.md §3)


def quaternion_to_matrix(quaternion: ArrayLike) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion (x, y, z, w), normalised first."""
    x, y, z, w = np.asarray(quaternion, dtype=np.float64) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(rotation: ArrayLike) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w ≥ 0 of a rotation matrix (Shepperd's method)."""
    r = np.asarray(rotation, dtype=np.float64)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > max(r[0, 0], r[1, 1], r[2, 2]):
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif r[1, 1] >= r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
    q = np.array(q) / np.linalg.norm(q)
    return -q if q[3] < 0.0 else q


def rotation_x(angle: float) -> np.ndarray:
    """Rotation matrix about x by angle [rad]."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class MocapConfig:
    """Frame conventions of the mocap chain: base quaternion (x, y, z, w), base and marker offsets
    [m]."""

    base_quaternion: tuple[float, float, float, float] = BASE_QUATERNION
    base_offset: tuple[float, float, float] = BASE_OFFSET
    marker_offset: tuple[float, float, float] = MARKER_OFFSET
    use_base_orientation: bool = False

    def __post_init__(self) -> None:
        """Validate that the configured quaternion and offsets are finite and of the right size."""
        if (
            len(self.base_quaternion) != 4
            or len(self.base_offset) != 3
            or len(self.marker_offset) != 3
        ):
            raise ValueError("base_quaternion needs 4 entries, base_offset and marker_offset 3")
        values = np.array(
            [*self.base_quaternion, *self.base_offset, *self.marker_offset], dtype=np.float64
        )
        if (
            not np.all(np.isfinite(values))
            or abs(np.linalg.norm(self.base_quaternion) - 1.0) > 1e-3
        ):
            raise ValueError(
                "offsets must be finite and base_quaternion a unit quaternion (x, y, z, w)"
            )

    @cached_property
    def base_rotation(self) -> np.ndarray:
        """R(q_base), the configured rotation of {0} in the world (and the body re-alignment)."""
        return quaternion_to_matrix(self.base_quaternion)


DEFAULT_CONFIG = MocapConfig()


def base_transform(
    base_position: ArrayLike,
    config: MocapConfig = DEFAULT_CONFIG,
    base_quaternion: ArrayLike | None = None,
) -> np.ndarray:
    """T_W0 (4, 4) from the measured base position (and orientation, if the config uses it)."""
    rotation = config.base_rotation
    if config.use_base_orientation:
        if base_quaternion is None:
            raise ValueError("use_base_orientation needs the measured base quaternion")
        rotation = quaternion_to_matrix(base_quaternion) @ rotation
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = np.asarray(base_position, dtype=np.float64) + rotation @ np.asarray(
        config.base_offset
    )
    return transform


def body_in_base(
    base: np.ndarray,
    position: ArrayLike,
    quaternion: ArrayLike,
    config: MocapConfig = DEFAULT_CONFIG,
) -> np.ndarray:
    """T_0B (4, 4) = T_W0⁻¹ · T_WB · [[R(q_base), 0], [0, 1]] for a body pose measured in the
    world."""
    r_w0 = base[:3, :3]
    transform = np.eye(4)
    transform[:3, :3] = r_w0.T @ quaternion_to_matrix(quaternion) @ config.base_rotation
    transform[:3, 3] = r_w0.T @ (np.asarray(position, dtype=np.float64) - base[:3, 3])
    return transform


def planar_pose(body: np.ndarray, config: MocapConfig = DEFAULT_CONFIG) -> np.ndarray:
    """χ_ee = [−p_y, p_z, −a_x] of the platform pose T_0B, with p the marker-offset-corrected EE
    point."""
    rotation = body[:3, :3]
    p = body[:3, 3] - rotation @ np.asarray(config.marker_offset)
    a_x = math.atan2(rotation[2, 1], rotation[2, 2])
    return np.array([-p[1], p[2], -a_x])


def world_to_planar(
    base_position: ArrayLike,
    platform_position: ArrayLike,
    platform_quaternion: ArrayLike,
    config: MocapConfig = DEFAULT_CONFIG,
    base_quaternion: ArrayLike | None = None,
) -> np.ndarray:
    """Planar EE pose χ_ee = [x, y, θ] in {0} from the measured world poses of base and platform
    bodies."""
    base = base_transform(base_position, config, base_quaternion)
    return planar_pose(body_in_base(base, platform_position, platform_quaternion, config), config)


def planar_to_world(
    chiee: ArrayLike,
    base_position: ArrayLike,
    config: MocapConfig = DEFAULT_CONFIG,
    base_quaternion: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and quaternion (x, y, z, w) of the platform body that maps to χ_ee
    (inverse chain)."""
    x, y, theta = np.asarray(chiee, dtype=np.float64)
    base = base_transform(base_position, config, base_quaternion)
    r_0b = rotation_x(-theta)
    t_0b = np.array([0.0, -x, y]) + r_0b @ np.asarray(config.marker_offset)
    position = base[:3, 3] + base[:3, :3] @ t_0b
    rotation = base[:3, :3] @ r_0b @ config.base_rotation.T
    return position, matrix_to_quaternion(rotation)


def pose_problem(position: ArrayLike, quaternion: ArrayLike, norm_tol: float = 1e-2) -> str | None:
    """Why a measured body pose is unusable (non-finite, quaternion norm off by > norm_tol), or None
    if it is fine."""
    position = np.asarray(position, dtype=np.float64)
    quaternion = np.asarray(quaternion, dtype=np.float64)
    if position.shape != (3,) or quaternion.shape != (4,):
        return f"bad shapes {position.shape} / {quaternion.shape}, expected (3,) / (4,)"
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))):
        return "non-finite position or quaternion"
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > norm_tol:
        return f"quaternion norm {norm:.6g} differs from 1 by more than {norm_tol}"
    return None


def jump_problem(
    previous: ArrayLike,
    current: ArrayLike,
    dt: float,
    max_speed: float = 1.0,
    max_angular_speed: float = 20.0,
) -> str | None:
    """Why the planar pose moved implausibly far within dt [s] (faster than max_speed or
    max_angular_speed), or None."""
    delta = np.asarray(current, dtype=np.float64) - np.asarray(previous, dtype=np.float64)
    distance = float(np.hypot(delta[0], delta[1]))
    if distance > max_speed * dt:
        return f"position jumped {distance:.6g} m in {dt:.6g} s (limit {max_speed} m/s)"
    if abs(delta[2]) > max_angular_speed * dt:
        return (
            f"angle jumped {abs(delta[2]):.6g} rad in {dt:.6g} s (limit {max_angular_speed} rad/s)"
        )
    return None


@dataclass(frozen=True)
class WorkspaceBox:
    """Plausibility box for χ_ee in {0} (a sanity bound on measurements, not the reachable set) [m,
    m, rad]."""

    x: tuple[float, float] = (-0.08, 0.08)
    y: tuple[float, float] = (0.06, 0.18)
    theta: tuple[float, float] = (-math.pi / 2, math.pi / 2)

    def problem(self, chiee: ArrayLike) -> str | None:
        """Why χ_ee lies outside the box, or None if it is inside."""
        values = np.asarray(chiee, dtype=np.float64)
        for label, value, (lo, hi) in zip(
            ("x", "y", "theta"), values, (self.x, self.y, self.theta)
        ):
            if not lo <= value <= hi:
                return f"{label} = {value:.6g} outside [{lo}, {hi}]"
        return None


def rest_pose_problem(
    chiee: ArrayLike,
    expected: ArrayLike = REST_POSE,
    position_tol: float = 0.01,
    angle_tol: float = 0.1,
) -> str | None:
    """Start-up check of the sign chain: why χ_ee of the robot at rest (φ = 0) differs from ≈ [0,
    0.110, 0], or None."""
    chiee = np.asarray(chiee, dtype=np.float64)
    delta = chiee - np.asarray(expected, dtype=np.float64)
    if not np.all(np.isfinite(delta)):
        return "non-finite rest pose"
    if float(np.hypot(delta[0], delta[1])) > position_tol or abs(delta[2]) > angle_tol:
        return (
            f"rest pose {np.round(chiee, 4).tolist()} differs from {list(expected)} by more than "
            f"{position_tol} m / {angle_tol} rad; check the base quaternion, offsets and Motive's "
            "axes"
        )
    return None

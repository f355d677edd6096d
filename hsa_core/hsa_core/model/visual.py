"""Drawable geometry of the planar HSA robot for RViz/Foxglove markers: backbone, rods and platform
as polylines.

Everything is in the planar base frame {0} (model.md §3; ROS frame ``hsa_base``,
docs/ros_interfaces.md): origin on the robot axis at the top surface of the motor plate, y₀ along
the hanging backbone (down in the world), x₀ towards virtual rod 2 (roff = +24 mm), and z₀ = x₀ × y₀
completing a right-handed frame (so planar angles, positive from x₀ towards y₀, are rotations about
+z₀, as REP-103 orients angles). A planar point [x, y] is the 3-D point [x, y, 0].

The positions are those of :mod:`hsa_core.model.kinematics` (model.md §6.1–6.2, smooth at κ = 0,
with the same κ rule), so the drawn end-effector is the FK end-effector: the rigid proximal caps run
straight from the motor plate (s < 0), the constant-strain active length s ∈ [0, l] is sampled at
``n_points`` arc lengths, and the distal caps and the plate ride rigidly on the backbone tip frame.
All functions are pure and vectorised; ``n_points`` is a static argument.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from hsa_core.model.kinematics import (
    KAPPA_SHIFT_KIN,
    apply_kappa_rule,
    end_effector_offset,
    points_in_base,
    strains,
)
from hsa_core.model.params import HsaParams

DEFAULT_POINTS = 16
"""Samples of the active length per polyline; the chord error of a bent rod is then below 0.1 mm (κ
≤ 15 1/m)."""


class RobotGeometry(NamedTuple):
    """Polylines and poses of one configuration in {0} [m, rad]; n = ``n_points``."""

    backbone: Array
    """(n + 3, 2): base origin, backbone start (0, l_pc), n active samples p(s), distal platform
    surface, EE."""
    rods: Array
    """(2, n + 2, 2) per virtual rod i: motor plate (roff_i, 0), n active samples p_i(s), distal-cap
    end."""
    platform: Array
    """(5, 2): closed outline of the w × h_p plate (local y from l_dc to l_dc + h_p on the backbone
    tip frame)."""
    platform_pose: Array
    """(3,): centre [x, y, θ] of the plate, p(l) + R(κl) [0, l_dc + h_p/2] (model.md §6.2)."""
    platform_orientation: Array
    """(4,): the plate's orientation as a quaternion [x, y, z, w] (planar_quaternion of θ = κl)."""
    end_effector: Array
    """(3,): end-effector pose χ_ee [x, y, θ], equal to kinematics.end_effector_pose."""


def arc_samples(params: HsaParams, n_points: int = DEFAULT_POINTS) -> Array:
    """The n_points arc lengths s_k = k l / (n_points − 1) at which the active length is sampled
    [m]."""
    return jnp.linspace(0.0, 1.0, n_points) * params.l


def robot_geometry(
    params: HsaParams, q: ArrayLike, n_points: int = DEFAULT_POINTS
) -> RobotGeometry:
    """Backbone, rod and platform polylines of configuration q (relative to ξ_eq) in {0}; see
    RobotGeometry."""
    if n_points < 2:
        raise ValueError(f"n_points must be at least 2, got {n_points}")
    xi = apply_kappa_rule(params, strains(params, q), KAPPA_SHIFT_KIN)
    zero = jnp.zeros(())
    roff = params.roff
    lateral = jnp.stack(
        [jnp.stack([zero, zero]), jnp.stack([roff[0], zero]), jnp.stack([roff[1], zero])]
    )
    # (3, n, 2)
    active = points_in_base(params, xi, arc_samples(params, n_points)[None, :], lateral[:, None, :])
    w, h_p = params.platform_size[0], params.platform_size[1]
    l_dc = params.l_dc
    tip_local = jnp.stack(
        [  # points on the backbone tip frame: distal surface, EE, both cap ends, plate corners
            jnp.stack([zero, l_dc + h_p]),
            end_effector_offset(params),
            jnp.stack([roff[0], l_dc]),
            jnp.stack([roff[1], l_dc]),
            jnp.stack([-w / 2, l_dc]),
            jnp.stack([w / 2, l_dc]),
            jnp.stack([w / 2, l_dc + h_p]),
            jnp.stack([-w / 2, l_dc + h_p]),
            jnp.stack([-w / 2, l_dc]),
            jnp.stack([zero, l_dc + h_p / 2]),
        ]
    )
    tip = points_in_base(params, xi, params.l, tip_local)
    # motor-plate ends of the caps (θ₀ = 0)
    plate_top = jnp.stack([lateral[:, 0], jnp.zeros(3)], axis=-1)
    theta_tip = xi[0] * params.l
    return RobotGeometry(
        backbone=jnp.concatenate([plate_top[:1], active[0], tip[:2]]),
        rods=jnp.concatenate([plate_top[1:, None], active[1:], tip[2:4, None]], axis=1),
        platform=tip[4:9],
        platform_pose=jnp.concatenate([tip[9], theta_tip[None]]),
        platform_orientation=planar_quaternion(theta_tip),
        end_effector=jnp.concatenate([tip[1], (theta_tip + params.chiee_off[2])[None]]),
    )


def geometry_fn(
    params: HsaParams, n_points: int = DEFAULT_POINTS
) -> Callable[[ArrayLike], RobotGeometry]:
    """q ↦ robot_geometry(params, q) compiled with the parameters as constants (only q is passed per
    call)."""
    return jax.jit(partial(robot_geometry, params, n_points=n_points))


def planar_quaternion(theta: ArrayLike) -> Array:
    """Quaternion [x, y, z, w] of the planar rotation by θ about z₀ (the orientation of a planar
    pose in 3-D)."""
    half = jnp.asarray(theta, dtype=jnp.float64) / 2.0
    zero = jnp.zeros_like(half)
    return jnp.stack([zero, zero, jnp.sin(half), jnp.cos(half)], axis=-1)

"""Foxglove SceneUpdate entities of the robot and of the goal, from hsa_core.model.visual geometry
(colours as marker_node).

Entity ``robot``: backbone and both virtual rods as line strips, the platform as a cube at its pose.
Entity ``goal``: a sphere at the desired EE position and a translucent ghost of q^d (backbone, rods,
platform outline). Planar points [x, y] of the frame {0} are drawn at z = 0. Pure conversion: no
ROS, no server.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    LinePrimitive,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from hsa_core.model.visual import RobotGeometry

BACKBONE = (0.9, 0.9, 0.9)
RODS = ((0.85, 0.33, 0.10), (0.00, 0.45, 0.74))  # virtual rod 1 (roff < 0), rod 2 (roff > 0)
PLATFORM = (0.55, 0.55, 0.6)
SETPOINT = (0.15, 0.8, 0.15)
GHOST = (0.3, 0.8, 1.0)


@dataclass(frozen=True)
class Style:
    """Sizes [m] and opacity of the drawing."""

    frame_id: str
    backbone_width: float
    rod_width: float
    plate_size: tuple[float, float, float]
    setpoint_diameter: float
    ghost_alpha: float


def robot_entity(g: RobotGeometry, stamp: Timestamp, style: Style) -> SceneEntity:
    """Backbone and rods as line strips, the platform as a cube at its pose."""
    x, y, _ = (float(v) for v in g.platform_pose)
    ox, oy, oz, ow = (float(v) for v in g.platform_orientation)
    sx, sy, sz = style.plate_size
    plate = CubePrimitive(
        pose=Pose(
            position=Vector3(x=x, y=y, z=0.0), orientation=Quaternion(x=ox, y=oy, z=oz, w=ow)
        ),
        size=Vector3(x=sx, y=sy, z=sz),
        color=color(PLATFORM, 1.0),
    )
    lines = [
        line(g.backbone, color(BACKBONE, 1.0), style.backbone_width),
        *(line(rod, color(rgb, 1.0), style.rod_width) for rod, rgb in zip(g.rods, RODS)),
    ]
    return SceneEntity(
        timestamp=stamp, frame_id=style.frame_id, id="robot", lines=lines, cubes=[plate]
    )


def goal_entity(
    g: RobotGeometry, goal_xy: tuple[float, float], stamp: Timestamp, style: Style
) -> SceneEntity:
    """Setpoint sphere at goal_xy and the translucent ghost of q^d (geometry g)."""
    d = style.setpoint_diameter
    sphere = SpherePrimitive(
        pose=pose(*goal_xy), color=color(SETPOINT, 1.0), size=Vector3(x=d, y=d, z=d)
    )
    ghost = color(GHOST, style.ghost_alpha)
    lines = [
        line(g.backbone, ghost, style.backbone_width),
        *(line(rod, ghost, style.rod_width) for rod in g.rods),
        line(g.platform, ghost, style.backbone_width),
    ]
    return SceneEntity(
        timestamp=stamp, frame_id=style.frame_id, id="goal", spheres=[sphere], lines=lines
    )


def line(points: np.ndarray, rgba: Color, width: float) -> LinePrimitive:
    """A line strip through planar points (z = 0), ``width`` [m] thick."""
    return LinePrimitive(
        points=[Point3(x=float(px), y=float(py), z=0.0) for px, py in points],
        thickness=float(width),
        color=rgba,
        pose=pose(0.0, 0.0),
    )


def pose(x: float, y: float) -> Pose:
    """Pose at planar position (x, y) with identity orientation."""
    return Pose(position=Vector3(x=float(x), y=float(y), z=0.0), orientation=Quaternion(w=1.0))


def color(rgb: tuple[float, ...], alpha: float) -> Color:
    """Foxglove Color of an RGB triple and an opacity."""
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=float(alpha))

"""ROS messages ↔ NumPy arrays and integer nanoseconds: the one place the nodes convert message
fields.

Readers take any object with the message's fields (rclpy messages, or messages decoded from a bag);
builders return rclpy messages. Orders as in the paper and the message definitions: χ_ee = [x, y,
θ], q = [κ_be, σ_sh, σ_ax], φ = [φ1, φ2], quaternions (x, y, z, w). Planar points lie at z = 0 of
the base frame {0}. Times are integer nanoseconds (a float of epoch seconds resolves only about 0.2
µs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PoseStamped
from numpy.typing import ArrayLike
from rosgraph_msgs.msg import Clock

from hsa_msgs.msg import CsConfiguration, PlanarActuation, PlanarPose

NS_PER_S = 1_000_000_000

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time → integer nanoseconds."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def stamp_s(stamp: Any) -> float:
    """builtin_interfaces/Time → seconds (float; for durations and plots, not for ordering
    stamps)."""
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_msg(ns: int) -> Time:
    """Integer nanoseconds (>= 0) → builtin_interfaces/Time."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def clock_msg(ns: int) -> Clock:
    """Integer nanoseconds (>= 0) → rosgraph_msgs/Clock (a /clock tick)."""
    return Clock(clock=stamp_msg(ns))


def position_quaternion(msg: Any) -> tuple[Vec3, Quat]:
    """geometry_msgs/PoseStamped → (position (x, y, z) [m], quaternion (x, y, z, w))."""
    p, o = msg.pose.position, msg.pose.orientation
    return (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)


def pose_stamped(
    stamp: Time, frame_id: str, position: ArrayLike, quaternion: ArrayLike
) -> PoseStamped:
    """geometry_msgs/PoseStamped of a position (x, y, z) [m] and a quaternion (x, y, z, w) in
    ``frame_id``."""
    msg = PoseStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in np.asarray(position, dtype=np.float64))
    o.x, o.y, o.z, o.w = (float(v) for v in np.asarray(quaternion, dtype=np.float64))
    return msg


def planar_point(x: float, y: float) -> Point:
    """geometry_msgs/Point of a planar position (x, y) [m], at z = 0."""
    return Point(x=float(x), y=float(y), z=0.0)


def planar_pose(msg: Any) -> np.ndarray:
    """hsa_msgs/PlanarPose → χ_ee = [x, y, θ]."""
    return np.array([msg.x, msg.y, msg.theta], dtype=np.float64)


def planar_pose_msg(chiee: ArrayLike) -> PlanarPose:
    """χ_ee = [x, y, θ] (the first three entries) → hsa_msgs/PlanarPose."""
    x, y, theta = (float(v) for v in np.asarray(chiee, dtype=np.float64)[:3])
    return PlanarPose(x=x, y=y, theta=theta)


def configuration(msg: Any) -> np.ndarray:
    """hsa_msgs/CsConfiguration → q = [κ_be, σ_sh, σ_ax]."""
    return np.array([msg.kappa_be, msg.sigma_sh, msg.sigma_ax], dtype=np.float64)


def configuration_msg(q: ArrayLike) -> CsConfiguration:
    """q = [κ_be, σ_sh, σ_ax] (the first three entries) → hsa_msgs/CsConfiguration."""
    kappa_be, sigma_sh, sigma_ax = (float(v) for v in np.asarray(q, dtype=np.float64)[:3])
    return CsConfiguration(kappa_be=kappa_be, sigma_sh=sigma_sh, sigma_ax=sigma_ax)


def actuation(msg: Any) -> np.ndarray:
    """hsa_msgs/PlanarActuation → φ = [φ1, φ2] [rad] (a copy: the message may be reused)."""
    return np.array(msg.phi, dtype=np.float64)


def actuation_msg(
    phi: ArrayLike, stamp: Time, frame_id: str = "", source_stamp: Time | None = None
) -> PlanarActuation:
    """φ = [φ1, φ2] [rad] → hsa_msgs/PlanarActuation stamped ``stamp`` (``source_stamp``: the state
    it came from)."""
    msg = PlanarActuation(phi=np.asarray(phi, dtype=np.float64))
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    if source_stamp is not None:
        msg.source_stamp = source_stamp
    return msg

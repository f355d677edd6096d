"""hsa_common.convert on real rosidl messages (no process, no DDS): hand-computed values and round
trips."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PoseStamped
from rclpy.time import Time as RclpyTime
from rosgraph_msgs.msg import Clock

from hsa_common import convert
from hsa_msgs.msg import CsConfiguration, PlanarActuation, PlanarPose

pytestmark = pytest.mark.ros


# --- stamps
# --------------------------------------------------------------------------------------------------


def test_stamp_ns_of_a_time_message() -> None:
    assert convert.stamp_ns(Time(sec=12, nanosec=345_678_901)) == 12_345_678_901
    assert convert.stamp_ns(Time(sec=0, nanosec=0)) == 0


def test_stamp_ns_keeps_every_nanosecond_of_an_epoch_stamp() -> None:
    # 2024-01-01T00:00:00.000000001 UTC: a float of seconds would round the last nanosecond away
    assert convert.stamp_ns(Time(sec=1_704_067_200, nanosec=1)) == 1_704_067_200_000_000_001


def test_stamp_ns_agrees_with_rclpy() -> None:
    stamp = Time(sec=1_700_000_000, nanosec=999_999_999)
    assert convert.stamp_ns(stamp) == RclpyTime.from_msg(stamp).nanoseconds


def test_stamp_ns_reads_any_object_with_the_fields() -> None:
    """Messages decoded from a bag are not rclpy classes."""
    assert convert.stamp_ns(SimpleNamespace(sec=3, nanosec=5)) == 3_000_000_005


def test_stamp_s_of_a_time_message() -> None:
    assert convert.stamp_s(Time(sec=2, nanosec=500_000_000)) == 2.5
    assert convert.stamp_s(Time(sec=7, nanosec=250_000)) == pytest.approx(7.00025, abs=1e-12)


def test_stamp_msg_splits_seconds_and_nanoseconds() -> None:
    stamp = convert.stamp_msg(12_345_678_901)
    assert isinstance(stamp, Time) and (stamp.sec, stamp.nanosec) == (12, 345_678_901)
    assert (convert.stamp_msg(1_000_000_000).sec, convert.stamp_msg(1_000_000_000).nanosec) == (
        1,
        0,
    )
    # NumPy integers from array maths are accepted
    assert convert.stamp_msg(np.int64(999)).nanosec == 999


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 1_000_000_000, 1_704_067_200_123_456_789])
def test_stamp_round_trip(ns: int) -> None:
    assert convert.stamp_ns(convert.stamp_msg(ns)) == ns
    assert convert.stamp_msg(ns) == RclpyTime(nanoseconds=ns).to_msg()


def test_clock_msg_carries_the_instant() -> None:
    msg = convert.clock_msg(40_025_000_000)
    assert isinstance(msg, Clock) and (msg.clock.sec, msg.clock.nanosec) == (40, 25_000_000)


# --- poses
# --------------------------------------------------------------------------------------------------


def test_position_quaternion_of_a_pose_stamped() -> None:
    msg = PoseStamped()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 0.1, -0.2, 0.3
    (
        msg.pose.orientation.x,
        msg.pose.orientation.y,
        msg.pose.orientation.z,
        msg.pose.orientation.w,
    ) = 0.0, 0.6, 0.0, 0.8
    assert convert.position_quaternion(msg) == ((0.1, -0.2, 0.3), (0.0, 0.6, 0.0, 0.8))


def test_pose_stamped_from_arrays_and_back() -> None:
    half = math.sqrt(0.5)
    stamp = Time(sec=5, nanosec=7)
    msg = convert.pose_stamped(stamp, "world", np.array([1.0, 2.0, 3.0]), (half, 0.0, 0.0, half))
    assert isinstance(msg, PoseStamped)
    assert msg.header.stamp == stamp and msg.header.frame_id == "world"
    assert (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z) == (1.0, 2.0, 3.0)
    assert (msg.pose.orientation.x, msg.pose.orientation.w) == (half, half)
    assert convert.position_quaternion(msg) == ((1.0, 2.0, 3.0), (half, 0.0, 0.0, half))


def test_planar_point_lies_at_z_zero() -> None:
    point = convert.planar_point(np.float64(0.012), -0.034)
    assert isinstance(point, Point) and (point.x, point.y, point.z) == (0.012, -0.034, 0.0)
    assert type(point.x) is float


def test_planar_pose_reads_x_y_theta_in_order() -> None:
    chiee = convert.planar_pose(PlanarPose(x=0.01, y=0.12, theta=-0.3))
    assert chiee.dtype == np.float64
    np.testing.assert_array_equal(chiee, [0.01, 0.12, -0.3])


def test_planar_pose_round_trip_and_first_three_entries() -> None:
    msg = convert.planar_pose_msg(np.array([0.01, 0.12, -0.3]))
    assert (msg.x, msg.y, msg.theta) == (0.01, 0.12, -0.3)
    np.testing.assert_array_equal(convert.planar_pose(msg), [0.01, 0.12, -0.3])
    # the χ̇_ee half of a [q̇, χ̇_ee] estimate
    tail = convert.planar_pose_msg((1.0, 2.0, 3.0, 4.0, 5.0, 6.0)[3:])
    assert (tail.x, tail.y, tail.theta) == (4.0, 5.0, 6.0)


def test_planar_pose_msg_carries_nan() -> None:
    """Rates that are not available yet travel as NaN, never as a made-up zero."""
    msg = convert.planar_pose_msg((math.nan,) * 3)
    assert all(math.isnan(v) for v in (msg.x, msg.y, msg.theta))


# --- configuration and actuation
# ------------------------------------------------------------------------------------


def test_configuration_reads_kappa_sigma_sh_sigma_ax_in_order() -> None:
    q = convert.configuration(CsConfiguration(kappa_be=-4.0, sigma_sh=0.02, sigma_ax=0.15))
    np.testing.assert_array_equal(q, [-4.0, 0.02, 0.15])


def test_configuration_round_trip_uses_the_first_three_entries() -> None:
    msg = convert.configuration_msg(np.array([-4.0, 0.02, 0.15, 9.0, 9.0, 9.0]))
    assert (msg.kappa_be, msg.sigma_sh, msg.sigma_ax) == (-4.0, 0.02, 0.15)
    np.testing.assert_array_equal(convert.configuration(msg), [-4.0, 0.02, 0.15])


def test_actuation_is_a_copy_of_phi() -> None:
    msg = PlanarActuation(phi=np.array([0.5, 1.25]))
    phi = convert.actuation(msg)
    np.testing.assert_array_equal(phi, [0.5, 1.25])
    msg.phi[0] = 3.0
    assert phi[0] == 0.5


def test_actuation_msg_round_trip_with_header_and_source_stamp() -> None:
    stamp, source = Time(sec=10, nanosec=25_000_000), Time(sec=9, nanosec=995_000_000)
    msg = convert.actuation_msg([0.5, 1.25], stamp, frame_id="hsa_base", source_stamp=source)
    assert isinstance(msg, PlanarActuation)
    assert (
        msg.header.stamp == stamp
        and msg.header.frame_id == "hsa_base"
        and msg.source_stamp == source
    )
    np.testing.assert_array_equal(convert.actuation(msg), [0.5, 1.25])


def test_actuation_msg_without_source_stamp_leaves_it_zero() -> None:
    msg = convert.actuation_msg(np.zeros(2), Time(sec=1, nanosec=0))
    assert (msg.source_stamp.sec, msg.source_stamp.nanosec) == (0, 0) and msg.header.frame_id == ""


def test_actuation_msg_refuses_a_wrong_length() -> None:
    """phi is float64[2]: the generated setter's size check (ROS_PYTHON_CHECK_FIELDS=1 in tests)
    applies."""
    with pytest.raises(AssertionError):
        convert.actuation_msg([0.1, 0.2, 0.3], Time())

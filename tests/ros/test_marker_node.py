"""marker_node as a real process: PlanarState and Setpoint in, MarkerArray out. The expected
geometry is computed here from hsa_core.model.kinematics (FK, backbone pose, rod positions), not
from hsa_core.model.visual."""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Iterator

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker, MarkerArray

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.model import kinematics as kin
from hsa_core.model.params import load_params
from hsa_msgs.msg import CsConfiguration, PlanarPose, PlanarState, Setpoint
from tests.ros.conftest import ParameterClient, start_process, stop_process, wait_for_line

pytestmark = pytest.mark.ros

FRAME = "test_base"
PERIOD_NS, T0_NS = 5_000_000, 1_760_000_000 * 10**9  # 200 Hz states
Q_DES = np.array([-6.0, 0.01, 0.25])
EXPECTED_IDS = {
    ("backbone", 0),
    ("rods", 0),
    ("rods", 1),
    ("platform", 0),
    ("setpoint", 0),
    ("ghost", 0),
    ("ghost", 1),
    ("ghost", 2),
    ("ghost", 3),
}
PARAMS = load_params("fpu")


@pytest.fixture
def marker_node() -> Iterator[subprocess.Popen]:
    """marker_node in /hsa with a non-default frame; stopped (and its exit code checked) at
    teardown."""
    proc = start_process(
        [
            find_executable("hsa_kinematics_node", "marker_node"),
            "--ros-args",
            "-r",
            "__ns:=/hsa",
            "-p",
            f"frame_id:={FRAME}",
        ]
    )
    wait_for_line(proc, "ready", timeout=120.0)
    yield proc
    assert stop_process(proc) == 0


def stamp(ns: int) -> Time:
    """builtin_interfaces Time of ns."""
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


def to_ns(t: Time) -> int:
    """ns of a builtin_interfaces Time."""
    return t.sec * 10**9 + t.nanosec


def configuration(i: int) -> np.ndarray:
    """q of state i: a bending sweep through κ = 0 with shear and elongation."""
    t = i * PERIOD_NS * 1e-9
    return np.array([12.0 * math.sin(2.0 * t), 0.02 * math.cos(3.0 * t), 0.3 + 0.1 * math.sin(t)])


def state(i: int) -> PlanarState:
    """PlanarState i with the FK end-effector of its q (velocities are not drawn)."""
    q = configuration(i)
    x, y, theta = np.asarray(kin.end_effector_pose(PARAMS, q))
    msg = PlanarState(
        chiee=PlanarPose(x=float(x), y=float(y), theta=float(theta)), velocity_valid=True
    )
    msg.header.stamp, msg.header.frame_id = stamp(T0_NS + i * PERIOD_NS), "hsa_base"
    msg.q = CsConfiguration(kappa_be=q[0], sigma_sh=q[1], sigma_ax=q[2])
    return msg


def points(marker: Marker) -> np.ndarray:
    """(n, 3) points of a marker."""
    return np.array([[p.x, p.y, p.z] for p in marker.points])


def check_robot(
    markers: dict[tuple[str, int], Marker], q: np.ndarray, ns: str, ids: tuple[int, ...]
) -> None:
    """Backbone from the base origin to the FK end-effector, rods from the motor plate through
    p_i(l)."""
    chiee = np.asarray(kin.end_effector_pose(PARAMS, q))
    backbone = points(markers[(ns if ns else "backbone", ids[0])])
    np.testing.assert_allclose(backbone[0], [0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(backbone[-1], [*chiee[:2], 0.0], atol=1e-12)
    tip = np.asarray(kin.backbone_pose(PARAMS, q, float(PARAMS.l)))
    assert np.min(np.linalg.norm(backbone[:, :2] - tip[:2], axis=1)) < 1e-12  # passes through p(l)
    rod_tips = np.asarray(kin.rod_positions(PARAMS, q, float(PARAMS.l)))
    for i, roff in enumerate(np.asarray(PARAMS.roff)):
        rod = points(markers[(ns if ns else "rods", ids[1 + i])])
        np.testing.assert_allclose(rod[0], [roff, 0.0, 0.0], atol=1e-15)
        assert np.min(np.linalg.norm(rod[:, :2] - rod_tips[i], axis=1)) < 1e-12
        np.testing.assert_allclose(
            np.linalg.norm(rod[-1, :2] - rod_tips[i]), float(PARAMS.l_dc), rtol=1e-9
        )


def test_markers_follow_the_state_and_setpoint_at_the_rate_limit(
    ros_node: Node, marker_node
) -> None:
    received: list[MarkerArray] = []
    ros_node.create_subscription(
        MarkerArray,
        "/hsa/markers",
        received.append,
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
    )
    states = ros_node.create_publisher(PlanarState, "/hsa/state", qos.SENSOR)
    setpoints = ros_node.create_publisher(Setpoint, "/hsa/setpoint", qos.LATCHED)
    deadline = time.monotonic() + 20.0
    while states.get_subscription_count() < 1 or setpoints.get_subscription_count() < 1:
        assert time.monotonic() < deadline, "marker_node did not subscribe"
        time.sleep(0.05)
    x, y, theta = np.asarray(kin.end_effector_pose(PARAMS, Q_DES))
    goal = Setpoint(
        chiee_des=PlanarPose(x=float(x), y=float(y), theta=float(theta)),
        q_des=CsConfiguration(kappa_be=Q_DES[0], sigma_sh=Q_DES[1], sigma_ax=Q_DES[2]),
    )
    goal.header.stamp = stamp(T0_NS - 10**9)
    setpoints.publish(goal)
    deadline = time.monotonic() + 60.0  # a budget of its own, after the subscription wait
    while not received:  # a new setpoint is drawn at once, with its own stamp while no state exists
        assert time.monotonic() < deadline, "no MarkerArray after the setpoint"
        time.sleep(0.05)
    assert {m.header.stamp.sec for m in received[0].markers} == {goal.header.stamp.sec}

    n = 600  # 3 s of 200 Hz states
    start = time.monotonic()
    for i in range(n):
        time.sleep(max(0.0, start + i * PERIOD_NS * 1e-9 - time.monotonic()))
        states.publish(state(i))
    time.sleep(0.5)
    # ≥ 3.5 s; longer when a loaded machine slows the stream down
    elapsed = time.monotonic() - start
    streamed = [a for a in received[1:] if to_ns(a.markers[0].header.stamp) >= T0_NS]
    # rate limit 20 Hz on the node clock: at most one array per 50 ms of the stream (+1 for the
    # first state)
    assert 10 <= len(streamed) <= 20 * elapsed + 2, (len(streamed), elapsed)
    last = -1
    for array in streamed:
        markers = {(m.ns, m.id): m for m in array.markers}
        assert set(markers) == EXPECTED_IDS and len(array.markers) == len(EXPECTED_IDS)
        stamps = {to_ns(m.header.stamp) for m in array.markers}
        assert len(stamps) == 1 and {m.header.frame_id for m in array.markers} == {FRAME}
        (ns,) = stamps
        i, rest = divmod(ns - T0_NS, PERIOD_NS)
        assert rest == 0 and 0 <= i < n and i > last, "stamp is not that of a newer published state"
        last = i
        check_robot(markers, configuration(i), "", (0, 0, 1))
        check_robot(markers, Q_DES, "ghost", (0, 1, 2))
        assert all(
            m.type == Marker.LINE_STRIP
            for key, m in markers.items()
            if key[0] in ("backbone", "rods", "ghost")
        )
        # translucent
        assert all(abs(m.color.a - 0.3) < 1e-6 for k, m in markers.items() if k[0] == "ghost")
        sphere, cube = markers[("setpoint", 0)], markers[("platform", 0)]
        assert sphere.type == Marker.SPHERE and cube.type == Marker.CUBE
        np.testing.assert_allclose(
            [sphere.pose.position.x, sphere.pose.position.y], [x, y], atol=1e-15
        )
        q = configuration(i)
        tip = np.asarray(kin.backbone_pose(PARAMS, q, float(PARAMS.l)))
        h_p = float(PARAMS.platform_size[1])
        centre = tip[:2] + float(PARAMS.l_dc + h_p / 2) * np.array(
            [-math.sin(tip[2]), math.cos(tip[2])]
        )
        np.testing.assert_allclose([cube.pose.position.x, cube.pose.position.y], centre, atol=1e-12)
        assert cube.pose.orientation.z == pytest.approx(math.sin(tip[2] / 2), abs=1e-12)
        assert cube.pose.orientation.w == pytest.approx(math.cos(tip[2] / 2), abs=1e-12)
        np.testing.assert_allclose(
            [cube.scale.x, cube.scale.y, cube.scale.z], [0.08, 0.012, 0.08], rtol=1e-12
        )
    assert last >= n - 20  # the newest states are drawn, not a backlog

    assert ParameterClient(ros_node, "/hsa/marker_node").set("rate", 4.0).successful
    count = len(received)
    start = time.monotonic()
    for i in range(n, n + 400):  # 2 s at a 4 Hz limit
        time.sleep(max(0.0, start + (i - n) * PERIOD_NS * 1e-9 - time.monotonic()))
        states.publish(state(i))
    time.sleep(0.5)
    assert 3 <= len(received) - count <= 4 * (time.monotonic() - start) + 2, len(received) - count

"""Regression by replay: a recorded mocap stream, played through a fresh real kinematics_node, regenerates the
recorded ``state`` messages.

Run 1: the test publishes a synthetic 200 Hz ee_pose stream (regular mocap stamps) into kinematics_node in /hsa while
bag_recorder records /hsa/ee_pose and /hsa/state. Run 2: bag_player plays only the recorded ee_pose, remapped to
/replay/ee_pose, into a second kinematics_node (fresh estimator) in /replay. Each regenerated state must equal the
recorded state with the same mocap stamp: q, pose, window fill and validity exactly, the Savitzky–Golay rates to
rounding, since the estimator saw the same samples with the same stamps.
"""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from hsa_bag.bagio import Bag
from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_msgs.msg import PlanarPoseStamped, PlanarState
from tests.ros.conftest import start_process, stop_process, wait_for_line, wait_until

pytestmark = pytest.mark.ros

RECEIVE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
N, PERIOD_NS, T0_NS = 400, 5_000_000, 1_760_000_000 * 10**9  # 2 s of 200 Hz mocap


def kinematics(namespace: str) -> subprocess.Popen:
    """A kinematics_node in ``namespace`` whose ee_pose queue holds the whole stream (no drops when it lags).

    The late-sample gate (``max_lag``, a real-time guard for the controller) is off: it drops whatever a loaded
    machine delays, and this test is about regenerating every state, not about timing.
    """
    return start_process([
        find_executable("hsa_kinematics_node", "kinematics_node"), "--ros-args", "-r", f"__ns:={namespace}",
        "-p", f"qos_overrides.{namespace}/ee_pose.subscription.depth:={N}", "-p", "max_lag:=0.0",
    ])  # fmt: skip


@pytest.fixture
def processes() -> Iterator[dict[str, subprocess.Popen]]:
    """Both kinematics nodes and the recorder, started together (start-up compiles JAX); stopped at teardown."""
    procs: dict[str, subprocess.Popen] = {}
    yield procs
    for proc in procs.values():
        stop_process(proc)


def pose(i: int) -> PlanarPoseStamped:
    """Sample i of a smooth synthetic EE motion around the rest pose, stamped like the mocap at 200 Hz."""
    t = i * PERIOD_NS * 1e-9
    msg = PlanarPoseStamped()
    ns = T0_NS + i * PERIOD_NS
    msg.header.stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
    msg.header.frame_id = "hsa_base"
    msg.pose.x = 0.004 * math.sin(math.pi * t)
    msg.pose.y = 0.110 + 0.002 * (1.0 - math.cos(math.pi * t))
    msg.pose.theta = -0.15 * math.sin(math.pi * t)
    return msg


def key(state: PlanarState) -> int:
    """Mocap stamp [ns] of a state."""
    return state.header.stamp.sec * 10**9 + state.header.stamp.nanosec


def content(state: PlanarState) -> np.ndarray:
    """Every numeric field of a state."""
    return np.array([
        state.chiee.x, state.chiee.y, state.chiee.theta, state.q.kappa_be, state.q.sigma_sh, state.q.sigma_ax,
        state.chiee_dot.x, state.chiee_dot.y, state.chiee_dot.theta, state.q_dot.kappa_be, state.q_dot.sigma_sh,
        state.q_dot.sigma_ax, float(state.velocity_valid), float(state.window_samples),
    ])  # fmt: skip


def test_replayed_mocap_regenerates_the_recorded_states(ros_node: Node, processes, tmp_path: Path) -> None:
    bag = tmp_path / "mocap_run"
    ee_pose = ros_node.create_publisher(PlanarPoseStamped, "/hsa/ee_pose", qos.SENSOR)
    live: list[PlanarState] = []
    replayed: list[PlanarState] = []
    ros_node.create_subscription(PlanarState, "/hsa/state", live.append, RECEIVE)
    ros_node.create_subscription(PlanarState, "/replay/state", replayed.append, RECEIVE)
    processes["original"] = kinematics("/hsa")
    processes["replay"] = kinematics("/replay")
    processes["recorder"] = start_process([
        find_executable("hsa_bag", "bag_recorder"), "--ros-args", "-p", f"output:={bag}",
        "-p", "topics:=[/hsa/ee_pose, /hsa/state]",
    ])  # fmt: skip
    for proc in processes.values():
        wait_for_line(proc, "ready", timeout=120.0)
    recorded_topics = ("/hsa/ee_pose", "/hsa/state")
    assert wait_until(lambda: all(
        any(s.node_name == "bag_recorder" for s in ros_node.get_subscriptions_info_by_topic(t)) for t in recorded_topics
    ), timeout=60.0), "bag_recorder did not subscribe"  # fmt: skip
    assert wait_until(lambda: ee_pose.get_subscription_count() >= 2, timeout=60.0), "ee_pose not matched by node and recorder"

    start = time.monotonic()
    for i in range(N):  # run 1: live
        time.sleep(max(0.0, start + i * PERIOD_NS * 1e-9 - time.monotonic()))
        ee_pose.publish(pose(i))
    wait_until(lambda: len(live) >= N, timeout=30.0)  # a loaded node works through its queue after the stream
    time.sleep(1.0)
    assert stop_process(processes.pop("recorder")) == 0

    with Bag(bag) as recorded:
        assert recorded.topics["/hsa/ee_pose"].count >= 0.98 * N
        recorded_states = (deserialize_message(d, PlanarState) for _, _, d in recorded.messages(["/hsa/state"]))
        states = {key(s): s for s in recorded_states}
    assert len(states) >= 0.98 * N and all(np.isfinite(content(s)[:6]).all() for s in states.values())
    assert sum(s.velocity_valid for s in states.values()) >= 0.9 * N

    player = start_process([  # run 2: replay of the recorded mocap only
        find_executable("hsa_bag", "bag_player"), str(bag), "--topics", "/hsa/ee_pose",
        "--remap", "/hsa/ee_pose:=/replay/ee_pose", "--wait-for-subscribers", "30", "--delay", "0.5",
    ])  # fmt: skip
    out, _ = player.communicate(timeout=120)
    assert player.returncode == 0, out
    wait_until(lambda: len(replayed) >= len(states), timeout=30.0)

    again = {key(s): s for s in replayed}
    common = sorted(states.keys() & again.keys())
    missing = [(k - T0_NS) // PERIOD_NS for k in sorted(states.keys() - again.keys())]
    assert len(common) >= 0.98 * len(states), f"{len(missing)} not regenerated, samples {missing[:3]}…{missing[-3:]}"
    for stamp in common:  # IK per sample: identical
        np.testing.assert_array_equal(content(again[stamp])[:6], content(states[stamp])[:6])
    identical = [np.allclose(content(again[s]), content(states[s]), rtol=1e-9, atol=1e-12, equal_nan=True)
                 for s in common]  # fmt: skip
    assert np.mean(identical) >= 0.95  # rates too, except after a sample one of the runs lost

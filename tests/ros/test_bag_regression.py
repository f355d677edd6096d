"""Regression by replay, in lockstep: a recorded mocap stream, played through a fresh real
kinematics_node, regenerates every recorded ``state`` message, identical, whatever the load of the
machine.

Run 1: bag_player plays a synthetic 200 Hz ee_pose bag (regular mocap stamps, log time = stamp) into
kinematics_node in /hsa while bag_recorder records /hsa/ee_pose and /hsa/state. Run 2: bag_player
plays only the recorded ee_pose, remapped to /replay/ee_pose, into a second kinematics_node (fresh
estimator) in /replay, and a second recorder records /replay/state. Every node runs with
``use_sim_time`` and ``lockstep``; the player owns /clock and publishes a sample only when the
participants have taken everything before it (hsa_core.sim.playback). So nothing is lost: run 1
records all N samples and N states, each at the simulated instant of its sample, and run 2
regenerates all N states with every field bit-identical (the estimator sees the same samples with
the same stamps in the same order).
"""

from __future__ import annotations

import math
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from hsa_bag.bagio import Bag
from hsa_bag.msgtypes import TypeRegistry
from hsa_bag.storage import SplitBagWriter
from hsa_common.launcher import find_executable
from hsa_msgs.msg import PlanarPoseStamped, PlanarState
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = pytest.mark.ros

N, PERIOD_NS, T0_NS = 400, 5_000_000, 1_760_000_000 * 10**9  # 2 s of 200 Hz mocap
LOCKSTEP = ["-p", "use_sim_time:=true", "-p", "lockstep:=true"]
INFINITE = QosTime(9223372036, 854775807)
MOCAP_OFFER = Qos(
    QosHistory.UNKNOWN,
    0,
    QosReliability.BEST_EFFORT,
    QosDurability.VOLATILE,
    INFINITE,
    INFINITE,
    QosLiveliness.AUTOMATIC,
    INFINITE,
    False,  # as a sensor-data publisher offers it
)


def kinematics(namespace: str) -> subprocess.Popen:
    """A kinematics_node in ``namespace``, in lockstep (its default ee_pose queue and late-sample
    gate)."""
    return start_process(
        [
            find_executable("hsa_kinematics_node", "kinematics_node"),
            "--ros-args",
            "-r",
            f"__ns:={namespace}",
            *LOCKSTEP,
        ]
    )


def recorder(namespace: str, bag: Path, topics: str) -> subprocess.Popen:
    """A bag_recorder in ``namespace`` recording ``topics`` (a YAML list) into ``bag``, in
    lockstep."""
    return start_process(
        [
            find_executable("hsa_bag", "bag_recorder"),
            "--ros-args",
            "-r",
            f"__ns:={namespace}",
            "-p",
            f"output:={bag}",
            "-p",
            f"topics:={topics}",
            *LOCKSTEP,
        ]
    )


def play(bag: Path, participants: list[str], *args: str) -> str:
    """bag_player in lockstep with ``participants`` to completion; its output (asserting exit code
    0)."""
    proc = start_process(
        [
            find_executable("hsa_bag", "bag_player"),
            str(bag),
            *args,
            "--ros-args",
            *LOCKSTEP,
            "-p",
            f"participants:=[{', '.join(participants)}]",
        ]
    )
    try:
        out, _ = proc.communicate(timeout=300)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, out
    return out


@pytest.fixture
def processes() -> Iterator[dict[str, subprocess.Popen]]:
    """The nodes of a run, stopped at teardown if the test did not stop them."""
    procs: dict[str, subprocess.Popen] = {}
    yield procs
    for proc in procs.values():
        stop_process(proc)


def pose(i: int) -> PlanarPoseStamped:
    """Sample i of a smooth synthetic EE motion around the rest pose, stamped like the mocap at 200
    Hz."""
    t = i * PERIOD_NS * 1e-9
    msg = PlanarPoseStamped()
    ns = T0_NS + i * PERIOD_NS
    msg.header.stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
    msg.header.frame_id = "hsa_base"
    msg.pose.x = 0.004 * math.sin(math.pi * t)
    msg.pose.y = 0.110 + 0.002 * (1.0 - math.cos(math.pi * t))
    msg.pose.theta = -0.15 * math.sin(math.pi * t)
    return msg


def mocap_bag(path: Path) -> Path:
    """A bag of the N synthetic samples on /hsa/ee_pose, each logged at its stamp."""
    registry = TypeRegistry()
    registry.ensure("hsa_msgs/msg/PlanarPoseStamped")
    writer = SplitBagWriter(path, registry.store)
    writer.open()
    handle = writer.add_topic("/hsa/ee_pose", "hsa_msgs/msg/PlanarPoseStamped", [MOCAP_OFFER])
    for i in range(N):
        writer.write(handle, T0_NS + i * PERIOD_NS, serialize_message(pose(i)))
    writer.close()
    return path


def key(state: PlanarState) -> int:
    """Mocap stamp [ns] of a state."""
    return state.header.stamp.sec * 10**9 + state.header.stamp.nanosec


def content(state: PlanarState) -> np.ndarray:
    """Every numeric field of a state."""
    return np.array(
        [
            state.chiee.x,
            state.chiee.y,
            state.chiee.theta,
            state.q.kappa_be,
            state.q.sigma_sh,
            state.q.sigma_ax,
            state.chiee_dot.x,
            state.chiee_dot.y,
            state.chiee_dot.theta,
            state.q_dot.kappa_be,
            state.q_dot.sigma_sh,
            state.q_dot.sigma_ax,
            float(state.velocity_valid),
            float(state.window_samples),
        ]
    )


def states_of(bag: Path, topic: str) -> list[tuple[int, PlanarState]]:
    """(log time, message) of every state recorded on ``topic``."""
    with Bag(bag) as recorded:
        return [(t, deserialize_message(d, PlanarState)) for _, t, d in recorded.messages([topic])]


def run(
    processes: dict[str, subprocess.Popen],
    namespace: str,
    played: Path,
    recorded: Path,
    topics: str,
    *player_args: str,
) -> str:
    """One lockstep run: kinematics_node and bag_recorder in ``namespace``, the player; the player's
    output."""
    processes["kinematics"] = kinematics(namespace)
    processes["recorder"] = recorder(namespace, recorded, topics)
    for proc in processes.values():
        wait_for_line(proc, "ready", timeout=180.0)
    out = play(played, [f"{namespace}/kinematics_node", f"{namespace}/bag_recorder"], *player_args)
    assert stop_process(processes.pop("recorder")) == 0  # closes the bag
    stop_process(processes.pop("kinematics"))
    return out


def test_replayed_mocap_regenerates_every_recorded_state(processes, tmp_path: Path) -> None:
    synthetic, first, second = (
        mocap_bag(tmp_path / "synthetic"),
        tmp_path / "mocap_run",
        tmp_path / "replay_run",
    )
    out = run(processes, "/hsa", synthetic, first, "[/hsa/ee_pose, /hsa/state]")  # run 1
    assert (
        f"published {N} messages in 1 pass(es)" in out and "lockstep: simulated time starts" in out
    ), out

    with Bag(first) as recorded:
        poses = [
            (t, deserialize_message(d, PlanarPoseStamped))
            for _, t, d in recorded.messages(["/hsa/ee_pose"])
        ]
    # every sample, at its instant
    assert [t for t, _ in poses] == [T0_NS + i * PERIOD_NS for i in range(N)]
    states = states_of(first, "/hsa/state")
    # a state per sample, in order
    assert [key(s) for _, s in states] == [T0_NS + i * PERIOD_NS for i in range(N)]
    # computed within the instant of its sample (simulated time)
    assert all(t == key(s) for t, s in states)
    assert all(np.isfinite(content(s)[:6]).all() for _, s in states)
    assert sum(s.velocity_valid for _, s in states) >= 0.9 * N

    run(
        processes,
        "/replay",
        first,
        second,
        "[/replay/state]",
        "--topics",
        "/hsa/ee_pose",
        "--remap",
        "/hsa/ee_pose:=/replay/ee_pose",  # run 2: replay of the recorded mocap only
    )
    again = states_of(second, "/replay/state")
    # every recorded state regenerated, at the same instant
    assert [t for t, _ in again] == [t for t, _ in states]
    for (_, original), (_, regenerated) in zip(
        states, again
    ):  # same samples, same order: bit-identical
        np.testing.assert_array_equal(content(regenerated), content(original))
        assert key(regenerated) == key(original)

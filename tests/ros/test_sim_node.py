"""sim_node as a real process: mocap poses of the resting plant at 200 Hz, and motion when the
driver commands φ."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.sensing.mocap import world_to_planar
from hsa_msgs.msg import PlanarActuation
from tests.ros.conftest import start_process, stop_process, wait_for_line, wait_until
from tests.ros.faults import DiagnosticsLog

pytestmark = pytest.mark.ros

BASE = (0.1, -0.2, 1.0)  # world position of the base body [m]
REST_FPU = (0.0, 0.11014, 0.0)  # χ_ee of the FPU model at rest (model.md §3)


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One sim_node for the module (JAX compilation is the slow part); yields its emulated port."""
    port = tmp_path_factory.mktemp("sim") / "ttyDXL"
    # hsa_core's persistent JAX cache speeds reruns
    proc = start_process(
        [
            find_executable("hsa_sim_node", "sim_node"),
            "--ros-args",
            "-p",
            f"port:={port}",
            "-p",
            f"base_position:={list(BASE)}",
        ]
    )
    wait_for_line(proc, "ready", timeout=180.0)
    yield port
    stop_process(proc)
    assert not port.exists(), "the emulated bus outlived the simulator"
    assert (
        "emulated bus removed with torque off on every servo (off since monotonic"
        in proc.stdout.read()
    )


def planar(msg: PoseStamped) -> np.ndarray:
    p, q = msg.pose.position, msg.pose.orientation
    return world_to_planar(BASE, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def collect(node, topic: str, count: int) -> list[PoseStamped]:
    """The messages of ``topic`` from the second one on, once ``count`` of them have arrived
    (however late they come; 60 s bound)."""
    received: list[PoseStamped] = []
    subscription = node.create_subscription(PoseStamped, topic, received.append, qos.SENSOR)
    assert wait_until(lambda: received, 20.0), f"nothing on {topic}"
    received.clear()
    wait_until(lambda: len(received) >= count, 60.0)
    node.destroy_subscription(subscription)
    return list(received)


def test_resting_plant_is_published_at_the_mocap_rate(sim, ros_node) -> None:
    poses = collect(ros_node, "/mocap/platform/pose", 360)
    assert len(poses) >= 360, f"only {len(poses)} poses in 60 s"
    stamps = [p.header.stamp.sec + 1e-9 * p.header.stamp.nanosec for p in poses]
    assert all(b > a for a, b in zip(stamps, stamps[1:])) and poses[-1].header.frame_id == "world"
    # one sample per mocap period (200 Hz) in the node's own stamps; a pose lost by the loaded
    # observer only widens a few gaps
    assert np.median(np.diff(stamps)) == pytest.approx(1 / 200, rel=0.01), "not 200 Hz"
    np.testing.assert_allclose(planar(poses[-1]), REST_FPU, atol=2e-5)
    base = collect(ros_node, "/mocap/base/pose", 1)[-1].pose.position
    assert (base.x, base.y, base.z) == pytest.approx(BASE)


def test_driver_commands_move_the_simulated_robot(sim, ros_node) -> None:
    """Equal twists elongate (y grows); φ₁ > φ₂ bends towards x > 0 with θ < 0 (model.md §3 sign
    convention); the emulator's diagnostics show the driver's traffic."""
    driver = start_process(
        [
            find_executable("hsa_dynamixel_driver", "dynamixel_driver"),
            "--ros-args",
            "-p",
            f"port:={sim}",
        ]
    )
    try:
        wait_for_line(driver, "torque on", timeout=60.0)
        pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
        diagnostics = DiagnosticsLog(ros_node)
        poses: list[PoseStamped] = []
        ros_node.create_subscription(PoseStamped, "/mocap/platform/pose", poses.append, qos.SENSOR)

        def drive(phi: tuple[float, float], reached) -> np.ndarray:
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline and not (poses and reached(planar(poses[-1]))):
                pub.publish(PlanarActuation(phi=np.array(phi)))
                time.sleep(0.05)
            return planar(poses[-1])

        chiee = drive((1.0, 1.0), lambda c: c[1] > REST_FPU[1] + 0.006)
        assert chiee[1] > REST_FPU[1] + 0.006, f"no elongation: χ_ee = {chiee}"
        assert abs(chiee[0]) < 1e-3 and abs(chiee[2]) < 1e-2, (
            f"equal twists bent the robot: χ_ee = {chiee}"
        )
        chiee = drive((2.0, 0.5), lambda c: c[0] > 0.01)
        assert chiee[0] > 0.01 and chiee[2] < -0.1, (
            f"φ₁ > φ₂ did not bend towards +x: χ_ee = {chiee}"
        )
        _, values = diagnostics.wait(
            "sim_node: emulator", lambda s, v: float(v["sync_reads_per_s"]) > 20.0
        )
        assert values["unresponsive_ids"] == "[]" and values["torque_21"] == "True"
    finally:
        assert stop_process(driver) in (0, 1)


def test_bad_parameter_exits_2_naming_it() -> None:
    proc = start_process(
        [find_executable("hsa_sim_node", "sim_node"), "--ros-args", "-p", "disturbance:=strong"]
    )
    output, _ = proc.communicate(timeout=60.0)
    assert proc.returncode == 2 and "'disturbance'" in output, output

"""sim_node's run-time payload (parameter ``payload_schedule``): malformed schedules are refused at
start naming the parameter; a scheduled mass lowers the published platform pose from its instant of
simulated time on."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.time import Time

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.sensing.mocap import world_to_planar
from tests.ros.conftest import start_process, stop_process, wait_for_line, wait_until
from tests.ros.faults import DiagnosticsLog

pytestmark = pytest.mark.ros

BASE = (0.0, 0.0, 0.0)
REST_FPU = (0.0, 0.11014, 0.0)  # χ_ee of the FPU model at rest (model.md §3)
LOAD_AT, MASS = (
    4.0,
    # [s of simulated time], [kg] (a mass of hsa_identification/config/campaign_example.yaml)
    0.437,
)
# [s] around the load instant: the test's estimate of the world's origin on the node clock
MARGIN = 0.25


def sim_node(*parameters: str):
    """Start sim_node with ``-p`` parameters."""
    args = [find_executable("hsa_sim_node", "sim_node"), "--ros-args"]
    for parameter in parameters:
        args += ["-p", parameter]
    return start_process(args)


@pytest.mark.parametrize(
    "schedule, reason",
    [
        ("[1.0, 0.2, 3.0]", "pairs"),
        ("[2.0, 0.2, 1.0, 0.0]", "increasing"),
        ("[1.0, -0.2]", ">= 0 kg"),
    ],
)
def test_a_malformed_schedule_exits_2_naming_the_parameter(schedule: str, reason: str) -> None:
    proc = sim_node(f"payload_schedule:={schedule}")
    output, _ = proc.communicate(timeout=60.0)
    assert proc.returncode == 2 and "'payload_schedule'" in output and reason in output, output


def test_the_platform_moves_down_from_the_scheduled_instant(tmp_path, ros_node) -> None:
    """Wall clock: poses stamped before the instant show the resting plant, those well after it the
    loaded one, lower (planar y grows: the robot hangs, +y is down); the world diagnostics report
    the mass."""
    poses: list[PoseStamped] = []
    ros_node.create_subscription(PoseStamped, "/mocap/platform/pose", poses.append, qos.SENSOR)
    diagnostics = DiagnosticsLog(ros_node)
    proc = sim_node(
        f"port:={tmp_path / 'ttyDXL'}", f"payload_schedule:=[0.0, 0.0, {LOAD_AT}, {MASS}]"
    )
    try:
        wait_for_line(proc, "ready", timeout=180.0)
        status, values = diagnostics.wait("sim_node: world", timeout=20.0)
        array = next(a for a in diagnostics.arrays if status in a.status)
        origin = Time.from_msg(array.header.stamp).nanoseconds * 1e-9 - float(values["sim_time"])
        diagnostics.wait("sim_node: world", lambda s, v: float(v["payload"]) == MASS, timeout=60.0)
        # more than 50 loaded poses, however late a loaded machine delivers them
        wait_until(
            lambda: (
                sum(
                    Time.from_msg(p.header.stamp).nanoseconds * 1e-9 - origin > LOAD_AT + 0.5
                    for p in list(poses)
                )
                > 50
            ),
            timeout=60.0,
            poll=0.2,
        )
    finally:
        assert stop_process(proc) == 0
    stamped = [
        (Time.from_msg(p.header.stamp).nanoseconds * 1e-9 - origin, planar(p)) for p in list(poses)
    ]
    before = [chiee for t, chiee in stamped if t < LOAD_AT - MARGIN]
    after = [chiee for t, chiee in stamped if t > LOAD_AT + 0.5]
    assert len(before) > 50 and len(after) > 50, (
        f"{len(before)} poses before, {len(after)} after the load"
    )
    np.testing.assert_allclose(before, np.tile(REST_FPU, (len(before), 1)), atol=2e-5)
    loaded = np.asarray(after)
    assert np.all(loaded[:, 1] > REST_FPU[1] + 5e-4), (
        f"not lowered by the payload: y = {loaded[:, 1].min()}"
    )
    assert np.all(np.abs(loaded[:, [0, 2]]) < 1e-6), (
        "a payload at the CoG_pl (0, 0) must not bend the robot"
    )


def planar(msg: PoseStamped) -> np.ndarray:
    """χ_ee of a published platform pose."""
    p, q = msg.pose.position, msg.pose.orientation
    return world_to_planar(BASE, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))

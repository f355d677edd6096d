"""planner_node and setpoint_sequencer as real processes: service answers, schedule, failure
reporting and finish."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.time import Time
from std_msgs.msg import String

from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_core.task.trajectories import FPU_STEPS_20230925
from hsa_msgs.msg import Setpoint
from hsa_msgs.srv import PlanSetpoint
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = pytest.mark.ros

# planning_and_control.md §2.2, FPU, exact model
P_DES = (0.00479247, 0.12781018)
PHI_SS = (1.9846028, 1.6323408)
Q_DES = (-1.1352565, 0.0080816386, 0.30410104)
THETA = -0.066980133
UNREACHABLE = (0.2, 0.05)


def _exe(name: str) -> str:
    """Installed console script of hsa_planner_node."""
    return find_executable("hsa_planner_node", name)


def _start_planner(*args: str) -> object:
    """A planner_node (FPU, static planner) with command-line ``args``, once it says it is ready."""
    proc = start_process([_exe("planner_node"), *args])
    wait_for_line(proc, "ready", timeout=180.0)
    return proc


@pytest.fixture(scope="module")
def planner() -> Iterator[None]:
    """One planner_node (FPU, static planner) in the root namespace for the whole module."""
    proc = _start_planner()
    yield
    assert stop_process(proc) == 0


def _sequencer(ns: str, *params: str, service: str = "/plan_setpoint") -> object:
    """A setpoint_sequencer in namespace ns using the planning service ``service`` (the root
    planner's by default)."""
    args = ["--ros-args", "-r", f"__ns:={ns}", "-r", f"plan_setpoint:={service}"]
    for p in params:
        args += ["-p", p]
    return start_process([_exe("setpoint_sequencer"), *args])


GATE = "/gate/plan_setpoint"
"""A planning service that exists only once a test starts a planner for it (:func:`_open_gate`)."""


def _open_gate() -> object:
    """A second planner_node serving GATE, ready: a sequencer pointed at GATE starts its schedule
    (service found, then its start delay) only from now on."""
    return _start_planner("--ros-args", "-r", f"plan_setpoint:={GATE}")


def test_plan_setpoint_service(planner, ros_node) -> None:
    diagnostics: list[DiagnosticArray] = []
    ros_node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    client = ros_node.create_client(PlanSetpoint, "/plan_setpoint", qos_profile=qos.SERVICE)
    assert client.wait_for_service(timeout_sec=10.0)

    ok = client.call(PlanSetpoint.Request(x=P_DES[0], y=P_DES[1]), timeout_sec=10.0)
    assert (
        ok.success and ok.status == PlanSetpoint.Response.STATUS_OK and ok.planner_used == "static"
    )
    np.testing.assert_allclose(ok.setpoint.phi_ss, PHI_SS, atol=2e-7)
    sp = ok.setpoint
    np.testing.assert_allclose(
        [sp.q_des.kappa_be, sp.q_des.sigma_sh, sp.q_des.sigma_ax], Q_DES, rtol=1e-6
    )
    assert (sp.chiee_des.x, sp.chiee_des.y) == P_DES and sp.chiee_des.theta == pytest.approx(
        THETA, abs=1e-8
    )
    assert (
        sp.header.frame_id == "hsa_base" and sp.header.stamp.sec > 0 and sp.optimality_error <= 1e-3
    )
    assert ok.iterations > 0 and 0.0 < ok.solve_time < 5.0

    far = client.call(PlanSetpoint.Request(x=UNREACHABLE[0], y=UNREACHABLE[1]), timeout_sec=10.0)
    assert (
        not far.success and far.status == PlanSetpoint.Response.STATUS_UNREACHABLE and far.message
    )
    nan = client.call(PlanSetpoint.Request(x=math.nan, y=0.12), timeout_sec=10.0)
    assert (
        not nan.success
        and nan.status == PlanSetpoint.Response.STATUS_INVALID_REQUEST
        and "finite" in nan.message
    )
    code = client.call(PlanSetpoint.Request(x=0.0, y=0.12, planner=9), timeout_sec=10.0)
    assert (
        code.status == PlanSetpoint.Response.STATUS_INVALID_REQUEST
        and "planner code 9" in code.message
    )
    rollout = client.call(
        PlanSetpoint.Request(x=0.0, y=0.12, planner=PlanSetpoint.Request.PLANNER_ROLLOUT),
        timeout_sec=10.0,
    )
    assert (
        rollout.status == PlanSetpoint.Response.STATUS_INVALID_REQUEST
        and "'planners'" in rollout.message
    )

    deadline = time.monotonic() + 5.0
    report = None
    while report is None and time.monotonic() < deadline:
        for array in list(diagnostics):
            for status in array.status:
                values = {kv.key: kv.value for kv in status.values}
                if status.name == "planner_node: planning" and int(values["requests"]) >= 5:
                    report = values
        time.sleep(0.1)
    assert report is not None, "no planner diagnostics counting the requests"
    assert report["failures UNREACHABLE"] == "1" and report["failures INVALID_REQUEST"] == "3"


def test_sequencer_schedule_failure_and_finish(planner, ros_node) -> None:
    received: dict[str, list[tuple[float, object]]] = {"a_sp": [], "a_st": [], "b_sp": []}

    def keep(key: str):  # noqa: ANN202 - tiny closure
        return lambda msg: received[key].append((time.monotonic(), msg))

    ros_node.create_subscription(Setpoint, "/a/setpoint", keep("a_sp"), qos.LATCHED)
    ros_node.create_subscription(String, "/a/sequencer_status", keep("a_st"), qos.LATCHED)
    ros_node.create_subscription(Setpoint, "/b/setpoint", keep("b_sp"), qos.LATCHED)
    points = [*P_DES, *UNREACHABLE, *FPU_STEPS_20230925[2]]
    # a latched subscription matched after point 1 would get only the newest setpoint: the
    # sequencers wait for GATE, served only once this node has discovered their publishers (a
    # fixed start delay was not enough beside two busy processes)
    custom = _sequencer(
        "/a",
        f"points:={points}",
        "rate:=2.0",
        "start_delay:=1.0",
        "exit_on_finish:=true",
        "finish_hold:=0.5",
        service=GATE,
    )
    steps = _sequencer("/b", "rate:=2.0", "start_delay:=1.0", service=GATE)
    bad = _sequencer("/c", "trajectory:=contour")
    gate = None
    try:
        topics = ("/a/setpoint", "/a/sequencer_status", "/b/setpoint")
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not all(ros_node.count_publishers(t) for t in topics):
            time.sleep(0.05)
        assert all(ros_node.count_publishers(t) for t in topics), "sequencers not discovered"
        gate = _open_gate()
        assert bad.wait(timeout=60.0) == 2
        assert "image_path" in bad.stdout.read()

        assert custom.wait(timeout=60.0) == 0, "exit_on_finish did not end the sequencer"
        log = custom.stdout.read()
        assert (
            "point 1 (0.2, 0.05) not planned: UNREACHABLE" in log
            and "setpoint 0 stays active" in log
        )

        sp = received["a_sp"]
        assert [m.trajectory_index for _, m in sp] == [0, 2], (
            "the failed point must not be published"
        )
        assert all(m.trajectory_length == 3 for _, m in sp)
        np.testing.assert_allclose(sp[0][1].phi_ss, PHI_SS, atol=2e-7)
        # planning stamps, not arrival times: a latched subscription that matched late gets setpoint
        # 0 only then
        planned = [Time.from_msg(m.header.stamp).nanoseconds * 1e-9 for _, m in sp]
        assert planned[1] - planned[0] == pytest.approx(1.0, abs=0.3), (
            "point 2 is due at t = 2 / rate"
        )

        statuses = [(t, json.loads(m.data)) for t, m in received["a_st"]]
        failed = [s for _, s in statuses if s["index"] == 1]
        assert failed and failed[0]["failures"] == 1 and failed[0]["setpoint_index"] == 0
        assert failed[0]["last_failure"]["status"] == "UNREACHABLE" and not failed[0]["finished"]
        t_end, last = statuses[-1]
        assert (
            last["finished"]
            and last["setpoint_index"] == 2
            and last["length"] == 3
            and last["failures"] == 1
        )
        assert t_end - sp[1][0] == pytest.approx(0.5, abs=0.3), (
            "finished after the last slot (t = 3 / rate)"
        )

        deadline = time.monotonic() + 20.0
        while len(received["b_sp"]) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        b = received["b_sp"]
        # a latched subscription that matched /b late gets the newest setpoint first (seen once:
        # 1, 2, 3): from there on every point, in order
        first = b[0][1].trajectory_index
        assert [m.trajectory_index for _, m in b[:3]] == [first, first + 1, first + 2]
        assert all(m.trajectory_length == 11 for _, m in b[:3])
        for (_, msg), expected in zip(b[:3], FPU_STEPS_20230925[first : first + 3]):
            assert (msg.chiee_des.x, msg.chiee_des.y) == pytest.approx(expected)
        assert np.diff(
            [Time.from_msg(m.header.stamp).nanoseconds * 1e-9 for _, m in b[:3]]
        ) == pytest.approx([0.5, 0.5], abs=0.2)
    finally:
        for proc in (custom, steps, bad, gate):
            if proc is not None:
                stop_process(proc)

"""E-stop through the whole sim graph (issue 6): the driver's `estop` service stops the real
controller from commanding (its latched `estop` topic) and no goal reaches the emulated servos; only
`clear_estop` resumes tracking, from zero integrators. The two sides are tested alone in
test_estop.py and test_controller_estop.py; this checks that they agree on the contract when wired
by sim.launch.yaml."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from hsa_common import qos
from hsa_msgs.msg import ControllerInfo, PlanarActuation
from tests.ros.conftest import start_process, stop_process, wait_for_line
from tests.ros.faults import BEST_EFFORT, fault, sec, wait_until

pytestmark = [pytest.mark.ros, pytest.mark.slow]
REPO = Path(__file__).resolve().parents[2]


def _trigger(node, name: str) -> Trigger.Response:
    """Call a std_srvs/Trigger service of the graph."""
    client = node.create_client(Trigger, name)
    assert client.wait_for_service(timeout_sec=20.0), f"{name} is not offered"
    response = client.call(Trigger.Request(), timeout_sec=10.0)
    assert response is not None, f"{name} did not answer"
    return response


def test_estop_service_stops_the_graph_until_cleared(tmp_path, ros_node) -> None:
    cmds: list[PlanarActuation] = []
    goals: list[PlanarActuation] = []
    infos: list[ControllerInfo] = []
    estop: list[bool] = []
    ros_node.create_subscription(PlanarActuation, "/hsa/phi_cmd", cmds.append, qos.COMMAND)
    ros_node.create_subscription(
        PlanarActuation, "/hsa/motor_goal_stamp", goals.append, BEST_EFFORT
    )
    ros_node.create_subscription(ControllerInfo, "/hsa/controller_info", infos.append, qos.INFO)
    ros_node.create_subscription(Bool, "/hsa/estop", lambda m: estop.append(m.data), qos.LATCHED)
    graph = start_process(
        [
            sys.executable,
            "-m",
            "hsa_common.launcher",
            str(REPO / "launch_scripts/sim.launch.yaml"),
            "record:=false",
        ],
        cwd=tmp_path,
    )
    try:
        wait_for_line(graph, "torque on", timeout=240.0)
        assert wait_until(lambda: len(goals) > 40, 120.0), (
            "the controller's commands did not reach the servos"
        )

        response = _trigger(ros_node, "/hsa/estop")
        stopped_at = ros_node.get_clock().now().nanoseconds * 1e-9
        assert response.success, response.message
        assert wait_until(lambda: estop and estop[-1], 5.0), (
            "the latched estop topic did not turn true"
        )
        assert wait_until(lambda: infos and infos[-1].state == ControllerInfo.STATE_STOPPED, 5.0)
        time.sleep(1.0)  # a second of E-stop: nothing may be commanded or written
        settle = stopped_at + 0.1  # commands already in flight when the service answered
        assert not [c for c in cmds if sec(c.header.stamp) > settle], (
            "the controller kept commanding"
        )
        assert not [g for g in goals if sec(g.header.stamp) > settle], (
            "goals were written during the E-stop"
        )
        stopped = [i for i in infos if i.state == ControllerInfo.STATE_STOPPED]
        assert stopped and all(np.all(np.asarray(i.e_int) == 0.0) for i in stopped), (
            "integrators not reset"
        )

        cleared_at = time.monotonic()
        response = _trigger(ros_node, "/hsa/clear_estop")
        assert response.success, response.message
        n_goals = len(goals)
        assert wait_until(lambda: len(goals) > n_goals + 10, 10.0), (
            "tracking did not resume after clear_estop"
        )
        resumed = time.monotonic() - cleared_at
        assert estop[-1] is False and infos[-1].state == ControllerInfo.STATE_TRACKING
        fault(
            "E-stop service on the whole sim graph",
            "latched estop true, controller STOPPED with zero "
            "integrators, no phi_cmd and no goal written for 1 s",
            f"clear_estop: 10 goals written after {resumed:.2f} s",
        )
    finally:
        stop_process(graph, timeout=20.0)

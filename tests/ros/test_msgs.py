"""hsa_msgs: the generated classes import, carry their documented constants, and travel between
processes."""

from __future__ import annotations

import time

import numpy as np
import pytest

from hsa_common import qos
from hsa_msgs.msg import ControllerInfo, PlanarActuation, PlanarState, Setpoint
from hsa_msgs.srv import CalibrateRestStrain, PlanSetpoint

pytestmark = pytest.mark.ros


def test_generated_classes_have_documented_fields() -> None:
    info = ControllerInfo()
    assert (
        info.phi_des_sat.shape == (2,)
        and info.motor_goal_angles.shape == (4,)
        and info.varphi.shape == (3,)
    )
    assert [
        ControllerInfo.STATE_WAITING_FOR_SETPOINT,
        ControllerInfo.STATE_TRACKING,
        ControllerInfo.STATE_HOLD_STALE,
        ControllerInfo.STATE_STOPPED,
    ] == [0, 2, 3, 4]
    cmd = PlanarActuation(phi=np.array([0.5, 1.0]))
    assert cmd.phi.dtype == np.float64
    with pytest.raises(AssertionError):
        # fixed size enforced (ROS_PYTHON_CHECK_FIELDS=1 in tests)
        PlanarActuation(phi=np.array([0.5, 1.0, 2.0]))
    assert Setpoint().phi_ss.shape == (2,)
    assert CalibrateRestStrain.Response().sigma_a_eq.shape == (2,)
    assert PlanSetpoint.Response.STATUS_PHI_OUT_OF_RANGE == 2


def test_message_and_service_between_processes(peer, ros_node) -> None:
    peer("msgs_peer")
    received: list[PlanarState] = []
    ros_node.create_subscription(PlanarState, "state", received.append, 10)
    client = ros_node.create_client(PlanSetpoint, "plan", qos_profile=qos.SERVICE)
    assert client.wait_for_service(timeout_sec=10.0), (
        "plan service of the peer process not discovered"
    )

    deadline = time.monotonic() + 10.0
    while len(received) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(received) >= 5, "no PlanarState messages arrived from the peer process"
    counts = [m.q.kappa_be for m in received]
    assert counts == sorted(counts) and received[-1].header.frame_id == "hsa_base"
    assert received[-1].chiee.y == pytest.approx(0.12) and received[-1].velocity_valid

    ok = client.call(
        PlanSetpoint.Request(x=0.01, y=0.125, planner=PlanSetpoint.Request.PLANNER_STATIC),
        timeout_sec=10.0,
    )
    assert ok is not None and ok.success and ok.status == PlanSetpoint.Response.STATUS_OK
    assert (ok.setpoint.chiee_des.x, ok.setpoint.chiee_des.y) == (0.01, 0.125)
    np.testing.assert_array_equal(ok.setpoint.phi_ss, [1.5, 2.5])

    bad = client.call(PlanSetpoint.Request(x=0.0, y=-0.1), timeout_sec=10.0)
    assert (
        bad is not None
        and not bad.success
        and bad.status == PlanSetpoint.Response.STATUS_UNREACHABLE
    )
    assert "above the base" in bad.message

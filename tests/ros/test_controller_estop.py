"""Emergency stop, controller side (issue 6): controller_node as a real process, fed ready states
and a setpoint by the test, which also plays the driver's latched ``estop`` topic (std_msgs/Bool,
reliable + transient local, depth 1).

While the E-stop is set the controller sends no phi_cmd, its integrators are zero (controller_info
STATE_STOPPED) and /diagnostics is ERROR; once cleared it tracks again from a fresh integrator
state. An E-stop latched before the controller matched the publisher holds too (late joiner)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Bool

from hsa_common import qos
from hsa_msgs.msg import ControllerInfo, PlanarActuation, Setpoint
from tests.ros.faults import DiagnosticsLog, NodeProcess, Recorder, fault, sec, setpoint, wait_until
from tests.ros.graphs import controller_alone
from tests.ros.test_controller_node import Feeder

pytestmark = pytest.mark.ros

NS = "/es"
PERIOD = 1.0 / 40.0
CONTROL = "controller_node: control loop"


@pytest.fixture(scope="module")
def controller() -> Iterator[NodeProcess]:
    """controller_node (FPU, P-satI-D, 40 Hz) in /es, diagnostics at 5 Hz."""
    yield from controller_alone(NS)


def _now(node) -> float:  # noqa: ANN001 - rclpy node
    """Node clock [s]."""
    return node.get_clock().now().nanoseconds * 1e-9


def _first_command_after(cmds: Recorder, t: float, timeout: float = 5.0) -> PlanarActuation:
    """The first phi_cmd stamped after t (waits for it)."""
    found: list[PlanarActuation] = []

    def arrived() -> bool:
        found[:] = [m for m in cmds.since(max(0, len(cmds) - 40)) if sec(m.header.stamp) > t]
        return bool(found)

    assert wait_until(arrived, timeout), "no command after the E-stop was cleared"
    return min(found, key=lambda m: sec(m.header.stamp))


def test_estop_stops_commands_resets_integrators_and_resumes_fresh(controller, ros_node) -> None:
    estop = ros_node.create_publisher(Bool, f"{NS}/estop", qos.LATCHED)
    # before the controller matched this publisher: it must still get it (latched)
    estop.publish(Bool(data=True))
    cmds = Recorder(ros_node, PlanarActuation, f"{NS}/phi_cmd")
    infos = Recorder(ros_node, ControllerInfo, f"{NS}/controller_info")
    diagnostics = DiagnosticsLog(ros_node)
    ros_node.create_publisher(Setpoint, f"{NS}/setpoint", qos.LATCHED).publish(setpoint())
    feeder = Feeder(ros_node, NS)
    try:
        t0 = _now(ros_node)
        status, values = diagnostics.wait(
            CONTROL, lambda s, v: v["estop"] == "True", after_ns=int(t0 * 1e9)
        )
        assert status.level == DiagnosticStatus.ERROR and "E-STOP" in status.message
        feeder.running.set()  # states only now: the order of discovery across topics is not defined
        time.sleep(1.0)
        assert len(cmds) == 0 and len(infos) == 0, (
            "commands while the latched E-stop was set at start"
        )

        t_clear = _now(ros_node)
        estop.publish(Bool(data=False))
        first = _first_command_after(cmds, t_clear)
        resume_start = sec(first.header.stamp) - t_clear
        # one second of tracking ticks (states judged stale by stamp on a loaded machine freeze the
        # law, not count)
        assert wait_until(
            lambda: (
                sum(m.state == ControllerInfo.STATE_TRACKING for m in infos.since()) >= 1.0 / PERIOD
            ),
            timeout=30.0,
        ), "fewer than 1 s of tracking ticks in 30 s"
        tracking = [m for m in infos.since() if m.state == ControllerInfo.STATE_TRACKING]
        assert np.all(np.abs(tracking[0].e_int) <= PERIOD + 1e-9), (
            "did not start from zero integrators"
        )
        before = tracking[-1]
        assert np.linalg.norm(before.e_int) > 0.1, (
            "the integrators should have grown while tracking"
        )

        n_infos = len(infos)
        t_stop = _now(ros_node)
        estop.publish(Bool(data=True))
        # 0.5 s of stopped ticks, however long the loaded machine takes to deliver them
        assert wait_until(
            lambda: (
                sum(m.state == ControllerInfo.STATE_STOPPED for m in infos.since(n_infos))
                >= 0.5 / PERIOD
            ),
            timeout=30.0,
        ), "fewer than 0.5 s of STATE_STOPPED ticks in 30 s"
        late = [sec(m.header.stamp) - t_stop for m in cmds.since() if sec(m.header.stamp) > t_stop]
        assert all(dt < 0.2 for dt in late), f"commands {late} s after the E-stop"
        stop_latency = max(late, default=0.0)
        after_stop = infos.since(n_infos)
        i_stop = next(
            i for i, m in enumerate(after_stop) if m.state == ControllerInfo.STATE_STOPPED
        )
        stopped = after_stop[i_stop:]
        assert all(m.state == ControllerInfo.STATE_STOPPED for m in stopped), (
            "controller_info does not report STATE_STOPPED on every tick"
        )
        for m in stopped:
            np.testing.assert_array_equal(m.e_int, [0.0, 0.0])
            assert np.all(np.isnan(m.phi_des_sat))
        status, values = diagnostics.wait(
            CONTROL,
            lambda s, v: s.level == DiagnosticStatus.ERROR,
            after_ns=int((t_stop + 0.3) * 1e9),
        )
        assert "E-STOP" in status.message and values["mode"] == "stopped (E-stop)"

        t_clear = _now(ros_node)
        estop.publish(Bool(data=False))
        first = _first_command_after(cmds, t_clear)
        resume = sec(first.header.stamp) - t_clear
        assert resume < 0.5, f"resumed {resume:.3f} s after the E-stop was cleared"
        time.sleep(0.3)
        resumed = [
            m
            for m in infos.since(n_infos)
            if m.state == ControllerInfo.STATE_TRACKING and sec(m.header.stamp) > t_clear
        ]
        assert resumed and np.all(np.abs(resumed[0].e_int) <= PERIOD + 1e-9), (
            "resumed with the old integrators"
        )
        _, values = diagnostics.wait(
            CONTROL, lambda s, v: v["mode"] == "tracking", after_ns=int(_now(ros_node) * 1e9)
        )
        assert values["estop"] == "False" and int(values["estop_events"]) == 2
    finally:
        feeder.close()
    assert len(controller.log("E-STOP")) == 2 and len(controller.log("E-stop cleared")) == 2
    fault(
        "E-stop latched before the controller matched",
        "no phi_cmd, diagnostics ERROR E-STOP",
        resume_start,
    )
    fault(
        "E-stop while tracking",
        f"{len(late)} phi_cmd stamped after it (last +{stop_latency:.3f} s), e_int reset "
        "to 0, controller_info STATE_STOPPED, diagnostics ERROR",
        resume,
    )

"""Emergency stop of the real dynamixel_driver on the MX-28 emulator (issue 6): services
``estop``/``clear_estop``, the latched ``estop`` topic, the ``estop_request`` subscription, and the
measured stop latency (request sent → the emulator executed torque-enable = 0 on every servo)."""

from __future__ import annotations

import time

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Bool

from hsa_common import qos
from hsa_msgs.msg import PlanarActuation
from hsa_sim_node.mx28_emulator import HW_OVERLOAD, MX28Emulator
from tests.ros import driver_harness as dh
from tests.ros.conftest import wait_until
from tests.ros.driver_fixtures import drivers, emulator
from tests.ros.faults import DiagnosticsLog, fault

pytestmark = pytest.mark.ros
__all__ = ["drivers", "emulator"]  # fixtures used by the tests below

# s: request → torque off on every servo (the shutdown requirement; the E-stop must be no slower)
STOP_BOUND = 0.1
# the SDK's wait for a status packet (about 34 ms): the emulator answers from a thread of this test
# process, which a loaded machine can leave unscheduled for longer
MISSED_STATUS = "There is no status packet"


def clear(services: dh.DriverServices, emulator: MX28Emulator) -> tuple[object, float]:
    """clear_estop as an operator uses it: asked again (at most 5 times) while the answer is a
    missed status packet, each such refusal leaving torque off; returns the last (response,
    sent)."""
    for _ in range(5):
        response, sent = services.call("clear_estop")
        if response.success or MISSED_STATUS not in response.message:
            break
        assert "E-stop stays engaged" in response.message, response.message
        assert wait_until(lambda: dh.torque(emulator) == {False}, 2.0), "torque on after a refusal"
    return response, sent


def test_estop_latches_torque_off_ignores_commands_and_only_the_service_clears_it(
    emulator, drivers, ros_node
) -> None:
    drivers.append(driver := dh.DriverProcess(emulator.port).wait_ready())
    assert wait_until(lambda: dh.torque(emulator) == {True}, timeout=10.0), driver.output()
    services = dh.DriverServices(ros_node)
    diagnostics = DiagnosticsLog(ros_node)
    latched: list[bool] = []
    ros_node.create_subscription(Bool, "estop", lambda m: latched.append(m.data), qos.LATCHED)
    assert wait_until(lambda: latched == [False], timeout=10.0), (
        f"no latched released state: {latched}"
    )
    pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
    request_pub = ros_node.create_publisher(Bool, "estop_request", qos.INFO)

    def drive(phi1: float, phi2: float, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pub.publish(dh.command(phi1, phi2))
            time.sleep(0.02)

    drive(0.5, 0.5, 0.3)
    assert dh.goal_writes(emulator), "commands did not reach the servos before the E-stop"

    # 1. Service: torque off at once, latched True, commands ignored, set_torque and estop_request
    #    False refused.
    response, sent = services.call("estop")
    assert response.success and "torque off confirmed" in response.message, response.message
    off = dh.torque_off_time(emulator, sent)
    assert off is not None and dh.torque(emulator) == {False}
    service_latency = off - sent
    assert service_latency < STOP_BOUND, f"E-stop took {service_latency * 1e3:.1f} ms"
    assert wait_until(lambda: latched[-1:] == [True], timeout=10.0)
    quiet_since = time.monotonic()
    drive(1.0, 1.0, 0.5)
    request_pub.publish(Bool(data=False))
    answer = services.set_torque(True)
    assert not answer.success and "clear_estop" in answer.message
    # the driver has taken (and ignored) commands, however late a loaded machine delivers them; a
    # report issued before the first of them counts none
    status, values = diagnostics.wait(
        "dynamixel_driver: estop",
        lambda s, v: v["engaged"] == "True" and int(v["ignored_commands"]) > 0,
        timeout=30.0,
    )
    assert status.level == DiagnosticStatus.ERROR and "estop service" in values["reason"]
    assert dh.goal_writes(emulator, quiet_since) == [], "a goal was written during the E-stop"
    assert dh.torque_on_time(emulator, quiet_since) is None and dh.torque(emulator) == {False}
    late: list[bool] = []
    ros_node.create_subscription(Bool, "estop", lambda m: late.append(m.data), qos.LATCHED)
    assert wait_until(lambda: late == [True], timeout=10.0), f"a late subscriber got {late}"
    fault(
        "E-stop service",
        f"torque off on all servos {service_latency * 1e3:.1f} ms after the request, latched "
        f"/estop True, {values['ignored_commands']} phi_cmd ignored, set_torque and estop_request "
        "False refused",
        "explicit clear_estop",
    )

    # 2. clear_estop: torque on holding the present positions, latched False, commands followed
    #    again.
    response, sent = clear(services, emulator)
    assert response.success, response.message
    on = dh.torque_on_time(emulator, sent)
    assert on is not None and dh.torque(emulator) == {True}
    assert wait_until(lambda: latched[-1:] == [False], timeout=10.0)
    resumed = time.monotonic()
    drive(1.0, 1.0, 0.3)
    assert dh.goal_writes(emulator, resumed), "commands not followed after clear_estop"
    fault(
        "E-stop clear",
        "clear_estop re-enables torque holding the present positions, /estop False, phi_cmd "
        "followed again",
        on - sent,
    )

    # 3. estop_request True (button / GUI): same stop; a hardware error makes clear_estop refuse and
    #    stay latched.
    sent = time.monotonic()
    request_pub.publish(Bool(data=True))
    assert wait_until(lambda: dh.torque_off_time(emulator, sent) is not None, 2.0), (
        "estop_request True did not stop"
    )
    topic_latency = dh.torque_off_time(emulator, sent) - sent
    assert topic_latency < STOP_BOUND, f"E-stop by topic took {topic_latency * 1e3:.1f} ms"
    assert wait_until(lambda: latched[-1:] == [True], timeout=10.0)
    emulator.set_hardware_error(22, HW_OVERLOAD)
    assert wait_until(lambda: bool(driver.log("hardware error")), 5.0), driver.output()
    response, _ = services.call("clear_estop")
    assert not response.success and "overload" in response.message
    assert dh.torque(emulator) == {False}
    assert latched[-1] is True
    emulator.set_hardware_error(22, 0)  # what a reboot does to the error
    assert wait_until(lambda: bool(driver.log("hardware errors cleared")), 5.0), driver.output()
    response, sent = clear(services, emulator)
    assert response.success and dh.torque(emulator) == {True}, response.message
    assert wait_until(lambda: latched[-1:] == [False], timeout=10.0)
    fault(
        "E-stop request topic",
        f"estop_request True: torque off in {topic_latency * 1e3:.1f} ms; clear_estop "
        "refused while a servo reports overload (stays latched), accepted after the error cleared",
        dh.torque_on_time(emulator, sent) - sent,
    )
    assert driver.proc.poll() is None


def test_estop_while_the_bus_is_down_stays_latched_across_the_reconnect(
    emulator, drivers, ros_node
) -> None:
    drivers.append(driver := dh.DriverProcess(emulator.port).wait_ready())
    assert wait_until(lambda: dh.torque(emulator) == {True}, timeout=10.0), driver.output()
    services = dh.DriverServices(ros_node)
    emulator.unplug()
    assert wait_until(lambda: bool(driver.log("bus lost")), 5.0), driver.output()
    response, _ = services.call("estop")
    assert response.success and "not connected" in response.message, response.message
    response, _ = services.call("clear_estop")
    assert not response.success and "not connected" in response.message
    replugged = time.monotonic()
    emulator.replug()
    assert wait_until(lambda: bool(driver.log("bus reconnected")), 10.0), driver.output()
    time.sleep(0.3)
    assert dh.torque_on_time(emulator, replugged) is None and dh.torque(emulator) == {False}, (
        "torque on during E-stop"
    )
    response, sent = clear(services, emulator)
    assert response.success and dh.torque(emulator) == {True}, response.message
    fault(
        "E-stop with the bus unplugged",
        "latched without bus access, clear refused while disconnected, torque "
        "stays off through the reconnect",
        dh.torque_on_time(emulator, sent) - sent,
    )

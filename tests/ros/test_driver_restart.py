"""Driver restart with the rods twisted, and a configured neutral that disagrees with the servos
(issue 10, item 2).

The real dynamixel_driver process with the real SDK on the MX-28 emulator of the test process: the
emulator outlives the driver (as hsa_sim_node's bus does), so a killed driver leaves the servos held
where they were. Every goal that reached the bus is read back from the emulator's register-write log
and checked against the absolute limits of the emulator's power-on (neutral) positions, computed
here from the spec, not by hsa_core.
"""

from __future__ import annotations

import math
import os
import signal
import time

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from hsa_common import qos
from hsa_msgs.msg import PlanarActuation
from hsa_sim_node.mx28_emulator import MX28Emulator
from tests.ros import driver_harness as dh
from tests.ros.conftest import wait_until
from tests.ros.driver_fixtures import drivers, emulator
from tests.ros.faults import DiagnosticsLog, fault

pytestmark = pytest.mark.ros
__all__ = ["drivers", "emulator"]  # fixtures used by the tests below

SIGN = {21: 1, 22: -1, 23: 1, 24: -1}  # spec §7: ψ = [+φ₂, −φ₂, +φ₁, −φ₁]
TWIST = 1.0  # rad, both rods, when the driver is killed


def spec_ticks(phi: float) -> dict[int, int]:
    """Goal ticks of φ₁ = φ₂ = ``phi`` by planning_and_control.md §7 around the emulator's neutral
    positions."""
    return {i: dh.NEUTRAL[i] + math.trunc(SIGN[i] * phi * dh.TICKS_PER_RAD) for i in dh.IDS}


def true_twists(emulator: MX28Emulator) -> list[float]:
    """φ of each motor from its present position and the emulator's (physical) neutral [rad]."""
    present = emulator.present_ticks()
    return [SIGN[i] * (present[i] - dh.NEUTRAL[i]) / dh.TICKS_PER_RAD for i in dh.IDS]


def outside_limits(emulator: MX28Emulator) -> list[tuple[int, int, int]]:
    """Every logged goal write outside the absolute limits: (ID, goal, ticks beyond the limit)."""
    found = []
    for write in dh.goal_writes(emulator):
        low, high = dh.clamp_range(write.dxl_id)
        if not low <= write.value <= high:
            found.append(
                (write.dxl_id, write.value, round(max(low - write.value, write.value - high)))
            )
    return found


@pytest.mark.parametrize("source", ["param", "read"])
def test_driver_killed_with_rods_twisted_restarts_without_moving_the_limits(
    emulator, drivers, ros_node, source: str
) -> None:
    """Both modes of the sim graph's kind: the configured neutral, and a read one that may only
    refine the φ map."""
    overrides = [f"neutral_source:={source}"]
    drivers.append(first := dh.DriverProcess(emulator.port, overrides).wait_ready())
    assert wait_until(lambda: dh.torque(emulator) == {True}, timeout=10.0), first.output()
    pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
    twisted = spec_ticks(TWIST)
    assert wait_until(
        lambda: emulator.present_ticks() == twisted,
        step=lambda: pub.publish(dh.command(TWIST, TWIST)),
        timeout=20.0,
    ), emulator.present_ticks()

    os.killpg(first.proc.pid, signal.SIGKILL)  # no shutdown hook: the servos stay held at φ = 1 rad
    first.proc.wait(timeout=10.0)
    killed = time.monotonic()
    assert dh.torque(emulator) == {True}
    drivers.append(second := dh.DriverProcess(emulator.port, overrides).wait_ready())
    assert wait_until(lambda: dh.torque_on_time(emulator, killed) is not None, timeout=20.0), (
        second.output()
    )
    restarted = dh.torque_on_time(emulator, killed) - killed
    # The same φ = 1 rad as before the kill: nothing may move (old main re-zeroed here and jumped to
    # φ = 2.06 rad).
    held = killed + restarted
    assert wait_until(
        # the command reached the new driver
        lambda: len(dh.goal_writes(emulator, held + 1e-3)) >= 8,
        step=lambda: pub.publish(dh.command(TWIST, TWIST)),
        timeout=20.0,
    ), second.output()
    for _ in range(25):
        pub.publish(dh.command(TWIST, TWIST))
        time.sleep(0.02)
    assert emulator.present_ticks() == twisted, (
        f"the twist moved at restart: {true_twists(emulator)} rad"
    )
    assert all(w.value == twisted[w.dxl_id] for w in dh.goal_writes(emulator, killed)), (
        dh.goal_writes(emulator, killed)
    )

    # Command φ up to and past the documented maximum: the goals stop at the limits of the power-on
    # neutral.
    reached = {}
    for phi in (2.0, dh.PHI_MAX, dh.PHI_MAX + 0.5):
        expected = spec_ticks(min(phi, dh.PHI_MAX))
        reached[phi] = wait_until(
            lambda: emulator.goal_ticks() == expected,  # noqa: B023 (within the iteration)
            step=lambda: pub.publish(dh.command(phi, phi)),
            timeout=10.0,  # noqa: B023
        )
    beyond = outside_limits(emulator)
    assert not beyond, f"{len(beyond)} goals beyond the absolute limits, e.g. {beyond[:4]}"
    assert all(reached.values()), (reached, emulator.goal_ticks(), second.output())
    assert wait_until(
        lambda: emulator.present_ticks() == spec_ticks(dh.PHI_MAX),
        step=lambda: pub.publish(dh.command(dh.PHI_MAX, dh.PHI_MAX)),
        timeout=20.0,
    )
    assert max(true_twists(emulator)) <= dh.PHI_MAX + 0.5 / dh.TICKS_PER_RAD
    fault(
        f"driver SIGKILLed with the rods twisted 1.0 rad, restarted (neutral_source {source})",
        "servos still held: the restarted driver keeps the pose (twist unchanged, "
        f"{len(dh.goal_writes(emulator))} goals all inside the absolute limits, phi_max + 0.5 rad "
        "stops at phi_max)",
        restarted,
    )


def test_configured_neutral_disagreeing_with_the_servos_refuses_torque(
    emulator, drivers, ros_node
) -> None:
    """Defaults (neutral_source param, neutral_ticks 2048) on servos whose neutral is elsewhere:
    torque stays off."""
    diagnostics = DiagnosticsLog(ros_node)
    drivers.append(
        driver := dh.DriverProcess(
            emulator.port, ["neutral_ticks:=[2048, 2048, 2048, 2048]"]
        ).wait_ready()
    )
    assert wait_until(lambda: bool(driver.log("torque stays off")), timeout=20.0), driver.output()
    [line] = driver.log("torque stays off")[:1]
    assert (
        "deviate from the configured neutral ticks" in line
        and "untwist the robot or re-home" in line
    )
    status, _ = diagnostics.wait(
        "dynamixel_driver: servos", lambda s, v: "neutral" in s.message, timeout=20.0
    )
    assert status.level == DiagnosticStatus.ERROR
    answer = dh.DriverServices(ros_node).set_torque(True)
    assert (
        not answer.success and "configured neutral" in answer.message and "\n" not in answer.message
    )
    pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
    for _ in range(20):
        pub.publish(dh.command(1.0, 1.0))
        time.sleep(0.02)
    assert dh.torque(emulator) == {False} and not dh.goal_writes(emulator), (
        "goals written with a disagreeing neutral"
    )
    fault(
        "configured neutral disagrees with the servos at start (no driver held them)",
        "torque stays off, one-line "
        "ERROR 'deviate from the configured neutral ticks … untwist the robot or re-home', "
        "set_torque refused",
        "manual",
    )


def test_disagreeing_neutral_file_refuses_torque_even_after_a_restart(
    emulator, drivers, ros_node, tmp_path
) -> None:
    """A persisted calibration 400 ticks off: refused at the first start and again at a restart
    (nothing adopts it)."""
    stored = tmp_path / "neutral.yaml"
    off_by_400 = [dh.NEUTRAL[i] + 400 for i in dh.IDS]
    stored.write_text(f"ids: {list(dh.IDS)}\nneutral_ticks: {off_by_400}\n")
    overrides = ["neutral_source:=file", f"neutral_file:={stored}"]
    for attempt in range(2):
        drivers.append(driver := dh.DriverProcess(emulator.port, overrides).wait_ready())
        assert wait_until(lambda: bool(driver.log("torque stays off")), timeout=20.0), (
            driver.output()
        )
        assert "deviate from the configured neutral ticks" in driver.log("torque stays off")[0]
        assert dh.torque(emulator) == {False} and not dh.goal_writes(emulator)
        os.killpg(driver.proc.pid, signal.SIGKILL)
        driver.proc.wait(timeout=10.0)
    assert (
        stored.read_text()
        == f"ids: {list(dh.IDS)}\nneutral_ticks: {[dh.NEUTRAL[i] + 400 for i in dh.IDS]}\n"
    )


def test_first_calibration_is_not_taken_from_held_servos(emulator, drivers, tmp_path) -> None:
    """No neutral file yet and the servos held twisted (torque on): nothing is stored, torque stays
    off."""
    for dxl_id, ticks in spec_ticks(TWIST).items():
        emulator.set_present_ticks(dxl_id, ticks)
        emulator.poke(dxl_id, dh.ADDR_GOAL, ticks)
        emulator.poke(dxl_id, dh.ADDR_TORQUE, 1)
    stored = tmp_path / "home" / "neutral.yaml"
    drivers.append(
        driver := dh.DriverProcess(
            emulator.port, ["neutral_source:=file", f"neutral_file:={stored}"]
        ).wait_ready()
    )
    assert wait_until(lambda: bool(driver.log("torque stays off")), timeout=20.0), driver.output()
    assert "servos were held at start" in driver.log("torque stays off")[0]
    assert not stored.exists() and dh.torque(emulator) == {False} and not dh.goal_writes(emulator)
    assert emulator.present_ticks() == spec_ticks(TWIST)

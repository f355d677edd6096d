"""dynamixel_driver as a real process (real dynamixel_sdk) against the MX-28 emulator running in the
test process."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import time
from collections.abc import Callable

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from hsa_common import qos
from hsa_core.model.params import CONFIG_DIR
from hsa_dynamixel_driver.bus import DynamixelBus
from hsa_msgs.msg import PlanarActuation
from hsa_sim_node.mx28_emulator import HW_OVERLOAD, MX28Emulator
from tests.ros.conftest import call_answered, stop_process, wait_for_line, wait_until
from tests.ros.driver_fixtures import driver, emulator
from tests.ros.driver_harness import IDS, NEUTRAL, PHI_MAX, clamp_range, torque

pytestmark = pytest.mark.ros
__all__ = ["driver", "emulator"]  # fixtures used by the tests below

TICK = math.pi / 2048


def spec_goal_ticks(phi1: float, phi2: float) -> dict[int, int]:
    """Goal ticks by planning_and_control.md §7, computed independently of hsa_core."""
    psi = {21: phi2, 22: -phi2, 23: phi1, 24: -phi1}
    return {i: NEUTRAL[i] + math.trunc(psi[i] * 2048 / math.pi) for i in IDS}


def assert_signal_turns_torque_off(
    proc: subprocess.Popen, sig: signal.Signals, emulator: MX28Emulator
) -> None:
    """Signal the driver's process group: it must exit by itself with every servo's torque off."""
    assert torque(emulator) == {True}
    os.killpg(proc.pid, sig)
    # The code is 0, or 1 when the signal's context shutdown races a publish or the executor's wait
    # set (a runner matter); the runner's hook has switched torque off either way.
    assert proc.wait(timeout=20.0) in (0, 1)
    assert torque(emulator) == {False}


def command(phi1: float, phi2: float, source: Time | None = None) -> PlanarActuation:
    return PlanarActuation(phi=np.array([phi1, phi2]), source_stamp=source or Time())


def test_phi_cmd_gives_spec_goal_ticks_state_comes_back_and_sigint_turns_torque_off(
    driver, emulator, ros_node, tmp_path
) -> None:
    # absent: the driver stores the present positions there
    stored = tmp_path / "home" / "neutral.yaml"
    proc = driver("neutral_source:=file", f"neutral_file:={stored}")
    assert wait_until(lambda: torque(emulator) == {True}, timeout=10.0), (
        "torque was not enabled at activation"
    )
    assert f"neutral_ticks: {[NEUTRAL[i] for i in IDS]}" in stored.read_text()
    states: list[JointState] = []
    present: list[PlanarActuation] = []
    goals: list[PlanarActuation] = []
    ros_node.create_subscription(JointState, "motor_states", states.append, qos.SENSOR)
    ros_node.create_subscription(PlanarActuation, "phi_present", present.append, qos.SENSOR)
    ros_node.create_subscription(PlanarActuation, "motor_goal_stamp", goals.append, qos.SENSOR)
    pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
    source = Time(sec=123, nanosec=456)
    expected = spec_goal_ticks(0.7, 1.3)

    def publish() -> None:
        pub.publish(command(0.7, 1.3, source))

    assert wait_until(lambda: emulator.goal_ticks() == expected, step=publish, timeout=10.0), (
        emulator.goal_ticks()
    )
    psi = [1.3, -1.3, 0.7, -0.7]
    assert wait_until(
        lambda: bool(states) and np.allclose(states[-1].position, psi, atol=TICK),
        step=publish,
        timeout=10.0,
    )
    assert states[-1].name == [f"motor_{i}" for i in IDS] and len(states[-1].velocity) == 4
    assert wait_until(
        lambda: bool(present) and np.allclose(present[-1].phi, [0.7, 1.3], atol=TICK), timeout=10.0
    )
    assert wait_until(lambda: bool(goals), timeout=10.0)
    assert (goals[-1].source_stamp.sec, goals[-1].source_stamp.nanosec) == (123, 456)
    assert np.allclose(goals[-1].phi, [0.7, 1.3], atol=TICK) and goals[-1].header.stamp.sec > 0

    assert_signal_turns_torque_off(proc, signal.SIGINT, emulator)


def test_goals_clamped_rate_limited_held_by_the_watchdog_and_stopped_by_hardware_errors(
    driver, emulator, ros_node
) -> None:
    proc = driver()
    assert wait_until(lambda: torque(emulator) == {True}, timeout=10.0)
    pub = ros_node.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND)
    seen: list[dict[int, int]] = []

    def send(phi1: float, phi2: float) -> Callable[[], None]:
        def step() -> None:
            pub.publish(command(phi1, phi2))
            seen.append(emulator.goal_ticks())

        return step

    saturated = spec_goal_ticks(PHI_MAX, 0.0)  # φ₁ clipped to φ_max, φ₂ to 0
    assert wait_until(
        lambda: emulator.goal_ticks() == saturated, step=send(50.0, -20.0), timeout=10.0
    ), emulator.goal_ticks()
    assert wait_until(
        lambda: emulator.goal_ticks() == spec_goal_ticks(0.0, PHI_MAX),
        step=send(-1e300, 1e300),
        timeout=10.0,
    )
    for bad in ((math.nan, 0.5), (math.inf, 0.5)):
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            send(*bad)()
            time.sleep(0.02)
        assert emulator.goal_ticks() == spec_goal_ticks(0.0, PHI_MAX), (
            "a non-finite command moved the servos"
        )

    # Rate limit (set at run time) and watchdog: ramp towards φ = 0 at 1 rad/s, stop commanding, the
    # goal holds.
    params = ros_node.create_client(SetParameters, "/dynamixel_driver/set_parameters")
    assert params.wait_for_service(timeout_sec=10.0)
    answer = params.call(
        SetParameters.Request(
            parameters=[Parameter("max_goal_rate", value=1.0).to_parameter_msg()]
        ),
        timeout_sec=10.0,
    )
    assert answer is not None and answer.results[0].successful
    start = emulator.goal_ticks()[21]
    started = time.monotonic()
    while time.monotonic() - started < 0.5:
        send(0.0, 0.0)()
        time.sleep(0.02)
    commanded = time.monotonic() - started
    time.sleep(1.0)
    held = emulator.goal_ticks()[21]
    time.sleep(0.5)
    assert emulator.goal_ticks()[21] == held, "the goal kept moving without fresh commands"
    assert NEUTRAL[21] < held < start, f"no ramp: {start} -> {held}"
    assert start - held <= (commanded + 0.5) * 2048 / math.pi, "faster than max_goal_rate"

    for goals in seen:
        for dxl_id, ticks in goals.items():
            low, high = clamp_range(dxl_id)
            assert low <= ticks <= high, (
                f"goal {ticks} of ID {dxl_id} outside [{low:.1f}, {high:.1f}]"
            )

    # An overload shuts servo 22 down: the driver switches every servo off and refuses torque-on
    # while it lasts.
    emulator.set_hardware_error(22, HW_OVERLOAD)
    assert wait_until(lambda: torque(emulator) == {False}, timeout=10.0), (
        "torque stayed on after a hardware error"
    )
    client = ros_node.create_client(SetBool, "set_torque")
    assert client.wait_for_service(timeout_sec=10.0)
    answer = call_answered(client, SetBool.Request(data=True))
    assert answer is not None and not answer.success and "overload" in answer.message
    assert proc.poll() is None


def test_set_torque_service_reconnect_after_unplug_and_sigterm_turns_torque_off(
    driver, emulator, ros_node
) -> None:
    proc = driver()
    assert wait_until(lambda: torque(emulator) == {True}, timeout=10.0)
    client = ros_node.create_client(SetBool, "set_torque")
    assert client.wait_for_service(timeout_sec=10.0)
    off = call_answered(client, SetBool.Request(data=False))
    assert off is not None and off.success and torque(emulator) == {False}
    on = call_answered(client, SetBool.Request(data=True))
    assert on is not None and on.success and torque(emulator) == {True}

    emulator.unplug()
    time.sleep(1.0)
    assert proc.poll() is None, "the driver died when the bus disappeared"
    emulator.replug()
    assert wait_until(lambda: torque(emulator) == {True}, timeout=15.0), (
        "torque not re-enabled after the replug"
    )
    states: list[JointState] = []
    ros_node.create_subscription(JointState, "motor_states", states.append, qos.SENSOR)
    assert wait_until(lambda: len(states) > 5, timeout=10.0), "no motor_states after the reconnect"

    assert_signal_turns_torque_off(proc, signal.SIGTERM, emulator)


def test_start_far_from_the_stored_neutral_keeps_torque_off(
    driver, emulator, ros_node, tmp_path
) -> None:
    stored = tmp_path / "neutral.yaml"
    stored.write_text(f"ids: {list(IDS)}\nneutral_ticks: {[NEUTRAL[i] + 400 for i in IDS]}\n")
    proc = driver("neutral_source:=file", f"neutral_file:={stored}")
    wait_for_line(proc, "torque stays off", timeout=30.0)  # the refusal at activation
    client = ros_node.create_client(SetBool, "set_torque")
    assert client.wait_for_service(timeout_sec=10.0)
    answer = call_answered(client, SetBool.Request(data=True))
    assert answer is not None and not answer.success and "neutral" in answer.message
    assert torque(emulator) == {False}


def test_bus_torque_off_still_works_after_an_exchange_cut_by_a_signal(emulator) -> None:
    """The shutdown hook's torque-off must not be blocked by the SDK state a KeyboardInterrupt can
    leave behind."""
    bus = DynamixelBus(emulator.port, 4_000_000, IDS)
    bus.open()
    bus.configure(torque_on=True)
    bus._port.is_using = True  # what an exception inside an SDK transaction leaves set
    assert bus.disable_torque() == frozenset() and torque(emulator) == {False}
    bus.close()


def test_lifecycle_without_autostart_publishes_state_only_while_active(
    driver, emulator, ros_node
) -> None:
    """autostart false: nothing until `configure` (no state publisher, bus closed); state publishers
    from configure, state and torque from activate; deactivate says torque off on the latched
    `torque` topic; cleanup removes them."""
    proc = driver("autostart:=false")
    states: list[JointState] = []
    reported: list[bool] = []
    ros_node.create_subscription(JointState, "motor_states", states.append, qos.SENSOR)
    ros_node.create_subscription(Bool, "torque", lambda m: reported.append(m.data), qos.LATCHED)
    lifecycle = ros_node.create_client(ChangeState, "dynamixel_driver/change_state")
    assert lifecycle.wait_for_service(timeout_sec=30.0)

    def transition(kind: int) -> None:
        response = lifecycle.call(
            ChangeState.Request(transition=Transition(id=kind)), timeout_sec=30.0
        )
        assert response is not None and response.success, kind

    assert wait_until(lambda: ros_node.count_publishers("torque") == 1, 30.0)
    assert not wait_until(lambda: ros_node.count_publishers("motor_states") > 0, 1.0), (
        "state publisher unconfigured"
    )
    transition(Transition.TRANSITION_CONFIGURE)
    assert wait_until(lambda: ros_node.count_publishers("motor_states") == 1, 30.0)
    assert not wait_until(lambda: bool(states), 0.5) and torque(emulator) == {False}
    transition(Transition.TRANSITION_ACTIVATE)
    assert wait_until(
        lambda: bool(states) and torque(emulator) == {True} and reported[-1:] == [True], 30.0
    )
    transition(Transition.TRANSITION_DEACTIVATE)
    assert torque(emulator) == {False} and wait_until(lambda: reported[-1:] == [False], 30.0), (
        reported
    )
    transition(Transition.TRANSITION_CLEANUP)
    assert wait_until(lambda: ros_node.count_publishers("motor_states") == 0, 30.0)
    assert stop_process(proc) in (0, 1) and torque(emulator) == {False}


def test_bad_parameters_exit_2_naming_the_parameter(driver) -> None:
    cases = {
        "baudrate": ("baudrate:=1234567",),
        "neutral_file": ("neutral_source:=file",),  # validator; cross-check
        # the model's material
        "params_file": ("material:=epu", f"params_file:={CONFIG_DIR / 'fpu.yaml'}"),
    }
    # started together: faster
    procs = {name: driver(*overrides, ready=False) for name, overrides in cases.items()}
    outputs = {name: proc.communicate(timeout=60.0)[0] for name, proc in procs.items()}
    for name, proc in procs.items():
        assert proc.returncode == 2, outputs[name]
        assert f"'{name}'" in outputs[name]
    refusal = [line for line in outputs["params_file"].splitlines() if "refusing to start" in line]
    assert len(refusal) == 1 and "is a 'fpu' set but material is 'epu'" in refusal[0], outputs[
        "params_file"
    ]

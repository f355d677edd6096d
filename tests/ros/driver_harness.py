"""Shared pieces of the driver fault tests (issue 6): the real dynamixel_driver process on an MX-28
emulator running in the test process, with its output collected, plus readings of the emulator's
timestamped register-write log."""

from __future__ import annotations

import math
import os
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from rclpy.node import Node
from std_srvs.srv import SetBool, Trigger

from hsa_common import rosenv
from hsa_common.launcher import find_executable
from hsa_msgs.msg import PlanarActuation
from hsa_sim_node.mx28_emulator import MX28Emulator, RegisterWrite, ServoModel
from tests.ros.conftest import CollectedProcess, wait_until

__all__ = [
    "ADDR_GOAL",
    "ADDR_TORQUE",
    "DRIVER",
    "IDS",
    "NEUTRAL",
    "NEUTRAL_PARAM",
    "PHI_MAX",
    "TICKS_PER_RAD",
    "DriverProcess",
    "DriverServices",
    "clamp_range",
    "command",
    "driver_args",
    "goal_writes",
    "make_emulator",
    "start_drivers",
    "torque",
    "torque_off_time",
    "torque_on_time",
    "wait_until",
]

DRIVER = find_executable("hsa_dynamixel_driver", "dynamixel_driver")
IDS = (21, 22, 23, 24)
NEUTRAL = {21: 1000, 22: 3000, 23: -500, 24: 5000}
SIGN = {21: 1, 22: -1, 23: 1, 24: -1}  # spec §7: ψ = [+φ₂, −φ₂, +φ₁, −φ₁]
PHI_MAX = math.radians(200.0)  # FPU parameter set
MARGIN = 0.02  # default goal_margin [rad]
TICKS_PER_RAD = 2048 / math.pi
ADDR_TORQUE, ADDR_GOAL = 64, 116
FAST_SERVO = ServoModel(time_constant_s=0.01, max_speed_ticks_per_s=50_000.0)
# the configured neutral = the emulator's power-on
NEUTRAL_PARAM = f"neutral_ticks:={[NEUTRAL[i] for i in IDS]}"


def make_emulator(tmp_path: Path, name: str = "ttyDXL") -> MX28Emulator:
    """A started emulator with the test neutrals and fast servos (stop it at teardown)."""
    return MX28Emulator(
        IDS, model=FAST_SERVO, initial_ticks=NEUTRAL, link_path=tmp_path / name
    ).start()


def driver_args(port: str, overrides: Sequence[str] = (), name: str | None = None) -> list[str]:
    """The driver's command line on ``port`` with the test neutral, a 0.2 s reconnect period and
    ``overrides`` (``name``: remap the node name)."""
    args = [DRIVER, "--ros-args"] + (["-r", f"__node:={name}"] if name is not None else [])
    args += ["-p", f"port:={port}", "-p", "reconnect_period:=0.2", "-p", NEUTRAL_PARAM]
    for override in overrides:
        args += ["-p", override]
    return args


class DriverProcess(CollectedProcess):
    """A dynamixel_driver process on ``port`` whose output is collected by a reader thread after
    ``ready``."""

    def __init__(
        self,
        port: str,
        overrides: Sequence[str] = (),
        env: dict[str, str] | None = None,
        name: str = "dynamixel_driver",
    ) -> None:
        args = driver_args(port, overrides, name)
        super().__init__(
            subprocess.Popen(
                args,
                env=rosenv.ros_environment({**os.environ, **(env or {})}),
                start_new_session=True,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
        )

    def wait_ready(self, timeout: float = 90.0) -> DriverProcess:
        """Block until the driver logged ``ready`` (see CollectedProcess)."""
        super().wait_ready(timeout)
        return self


def start_drivers(specs: Sequence[tuple[str, str, dict[str, str] | None]]) -> list[DriverProcess]:
    """Start several drivers (node name, port, extra env) at once — they import in parallel — and
    wait for each."""
    procs = [DriverProcess(port, env=env, name=name) for name, port, env in specs]
    for proc in procs:
        proc.wait_ready()
    return procs


def torque(emulator: MX28Emulator) -> set[bool]:
    """The set of torque states of the four servos ({True}: all on, {False}: all off)."""
    return {emulator.torque_enabled(i) for i in IDS}


def _torque_time(emulator: MX28Emulator, since: float, value: int) -> float | None:
    """Time of the first logged torque write of ``value`` after ``since`` by which every servo had
    that value."""
    firsts: dict[int, float] = {}
    for write in emulator.writes(ADDR_TORQUE, since):
        if write.value == value:
            firsts.setdefault(write.dxl_id, write.time)
    return max(firsts.values()) if len(firsts) == len(IDS) else None


def torque_off_time(emulator: MX28Emulator, since: float) -> float | None:
    """When (CLOCK_MONOTONIC) the last of the four servos got its first torque-off write after
    ``since``."""
    return _torque_time(emulator, since, 0)


def torque_on_time(emulator: MX28Emulator, since: float) -> float | None:
    """When the last of the four servos got its first torque-on write after ``since``."""
    return _torque_time(emulator, since, 1)


def goal_writes(emulator: MX28Emulator, since: float = -math.inf) -> list[RegisterWrite]:
    """Goal Position writes logged since ``since``."""
    return emulator.writes(ADDR_GOAL, since)


def clamp_range(dxl_id: int) -> tuple[float, float]:
    """Goal range in ticks of a motor: neutral + sign·[0, φ_max]·2048/π widened by the margin."""
    ends = sorted((0.0, SIGN[dxl_id] * PHI_MAX))
    return (
        NEUTRAL[dxl_id] + (ends[0] - MARGIN) * TICKS_PER_RAD,
        NEUTRAL[dxl_id] + (ends[1] + MARGIN) * TICKS_PER_RAD,
    )


def command(phi1: float, phi2: float) -> PlanarActuation:
    """A phi_cmd message (ROS_PYTHON_CHECK_FIELDS accepts non-finite floats in a float64 array)."""
    return PlanarActuation(phi=np.array([phi1, phi2], dtype=np.float64))


class DriverServices:
    """Clients of the driver's set_torque, estop and clear_estop (and optionally reboot) services,
    created once and matched before use (the first request of a client that was just discovered can
    wait for DDS matching, which is not the driver's latency)."""

    def __init__(self, node: Node, reboot: bool = False) -> None:
        names = [("set_torque", SetBool), ("estop", Trigger), ("clear_estop", Trigger)]
        if reboot:  # the reboot service for all servos and one per ID
            names += [("reboot", Trigger)] + [(f"reboot_{i}", Trigger) for i in IDS]
        self._clients = {name: node.create_client(srv, name) for name, srv in names}
        for name, client in self._clients.items():
            assert client.wait_for_service(timeout_sec=20.0), f"service {name} not available"
        time.sleep(0.5)  # let the response readers match too

    def call(self, name: str, request: object = None) -> tuple[object, float]:
        """The response of one call and when its request left (monotonic)."""
        client = self._clients[name]
        sent = time.monotonic()
        response = client.call(
            request if request is not None else client.srv_type.Request(), timeout_sec=10.0
        )
        assert response is not None, f"no answer from {name}"
        return response, sent

    def set_torque(self, on: bool) -> SetBool.Response:
        """The driver's set_torque service."""
        return self.call("set_torque", SetBool.Request(data=on))[0]

    def reboot(self, dxl_id: int | None = None) -> tuple[Trigger.Response, float, float]:
        """The driver's reboot service (all servos) or reboot_<dxl_id>: the response, when the
        request left and when the response came back (monotonic)."""
        response, sent = self.call("reboot" if dxl_id is None else f"reboot_{dxl_id}")
        return response, sent, time.monotonic()

"""dynamixel_driver: lifecycle node between ``phi_cmd`` and the 4 MX-28 servos (one sync write + one sync read a cycle).

Safety (planning_and_control.md §5, §7; ecosystem.md §2): goals are clipped to [0, φ_max], clamped to absolute tick
limits around the configured neutral ticks (parameter or persisted calibration, never a value read at start) and
rate-limited whatever arrives; torque goes off on deactivate, cleanup, shutdown, error, SIGINT/SIGTERM, uncaught
exceptions and the E-stop (latched until ``clear_estop``); torque is enabled only while the servos answer, report no
hardware error and their present positions are sane; a command watchdog holds or relaxes the motors; bus errors are
counted and reported, and the bus is reopened every ``reconnect_period`` while it is down. See
docs/nodes/hsa_dynamixel_driver.md.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.time import Time
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from hsa_common import lockstep, qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.actuation import (
    DEFAULT_MAX_GOAL_RATE,
    MotorLimits,
    MotorMap,
    RejectionLog,
    accept_read_neutral,
    neutral_check,
    ticks_to_angles,
)
from hsa_core.params import ParameterError, load_params
from hsa_core.jaxsetup import configure_jax
from hsa_dynamixel_driver.bus import (
    ADDR_TORQUE_ENABLE,
    SDK_BAUDRATES,
    VELOCITY_UNIT_RAD_S,
    BusError,
    CommError,
    DynamixelBus,
    PortError,
    ServoStatusError,
    describe_hardware_error,
)
from hsa_dynamixel_driver.supervision import GoalRateLimiter, reboot_refusal
from hsa_msgs.msg import PlanarActuation

SUCCESS = TransitionCallbackReturn.SUCCESS
FAULT_FILE_ENV = "HSA_DRIVER_FAULT_FILE"  # test hook: the control cycle raises while this file exists
REBOOT_WAIT_S = 2.0  # wall-clock wait for rebooted servos to answer a ping again (bus-level, like the SDK timeouts)


class InjectedFault(RuntimeError):
    """The uncaught exception raised by the test hook named in FAULT_FILE_ENV."""


def _signs(value: list[int]) -> str | None:
    return None if all(v in (-1, 1) for v in value) else "entries must be +1 or -1"


def _ids(value: list[int]) -> str | None:
    return None if len(set(value)) == len(value) else "IDs must be distinct"


SPECS = (
    ParamSpec("autostart", True, "configure and activate at start (no lifecycle manager needed)", read_only=True),
    ParamSpec("port", "/dev/ttyUSB0", "serial device of the U2D2 (a stable udev symlink is best)", read_only=True),
    ParamSpec("baudrate", 4_000_000, "bus speed [bit/s]; must equal the servos' Baud Rate register", read_only=True,
              validator=lambda v: None if v in SDK_BAUDRATES else f"must be one of {SDK_BAUDRATES}"),
    ParamSpec("motor_ids", [21, 22, 23, 24], "Dynamixel IDs; motors 1-2 drive rod 2 (+24 mm), 3-4 rod 1",
              low=0, high=252, length=4, read_only=True, validator=_ids),
    ParamSpec("rho", [1, -1, 1, -1], "rod handedness of each motor [+1|-1]", length=4, read_only=True,
              validator=_signs),
    ParamSpec("h", [1, 1], "control handedness of the two virtual rods [+1|-1]", length=2, read_only=True,
              validator=_signs),
    ParamSpec("material", "fpu", "parameter set giving phi_max", choices=("fpu", "epu"), read_only=True),
    ParamSpec("params_file", "", "parameter YAML overriding the packaged set (empty = packaged)", read_only=True),
    ParamSpec("phi_max", 0.0, "twist limit [rad]; 0 = the smaller phi_max of the parameter set", low=0.0,
              high=2.0 * math.pi, read_only=True),
    ParamSpec("goal_margin", 0.02, "goal clamp widening beyond [0, phi_max] on both ends [rad]", low=0.0, high=0.5,
              read_only=True),
    ParamSpec("neutral_source", "param", "neutral ticks (and so the absolute goal limits): the neutral_ticks list, "
              "neutral_file, or read (the φ map only, accepted within neutral_tolerance of neutral_ticks; the limits "
              "stay on neutral_ticks)", choices=("param", "file", "read"), read_only=True),
    ParamSpec("neutral_ticks", [2048, 2048, 2048, 2048], "configured neutral positions [ticks] (neutral_source "
              "'param' or 'read'); the default is the emulated servos' power-on position", length=4,
              low=-1_000_000, high=1_000_000, read_only=True),
    ParamSpec("neutral_file", "", "YAML of stored neutral ticks; written from the present positions if absent",
              read_only=True),
    ParamSpec("neutral_tolerance", 0.1, "largest |present - stored neutral| at start-up for torque-on [rad]",
              low=0.0, high=math.pi, read_only=True),
    ParamSpec("return_delay", 0, "Return Delay Time written at configure [2 us units]", low=0, high=254,
              read_only=True),
    ParamSpec("rate", 100.0, "control cycle rate: one sync write + one sync read [Hz]", low=1.0, high=500.0,
              read_only=True),
    ParamSpec("max_goal_rate", DEFAULT_MAX_GOAL_RATE, "largest goal speed of a motor [rad/s] (default: twice the "
              "MX-28 no-load speed); 0 = no rate limit", low=0.0, high=100.0),
    ParamSpec("write_on_command", True, "sync-write a goal as soon as a phi_cmd arrives (else only in the cycle); "
              "the read cycle, watchdog and rate limit are unchanged", read_only=True),
    ParamSpec("command_timeout", 0.1, "command watchdog: phi_cmd older than this [s] -> watchdog_action; 0 = off",
              low=0.0, high=10.0),
    ParamSpec("watchdog_action", "hold", "when the watchdog expires: hold the last goal, or relax (torque off until "
              "the next phi_cmd, which re-enables torque if safe)", choices=("hold", "relax")),
    ParamSpec("reconnect_period", 1.0, "retry period while the bus is down [s]", low=0.05, high=60.0,
              read_only=True),
    ParamSpec("packet_timeout", 0.0, "[ms] least time to wait for a status packet; 0 = the SDK's (about 34 ms). "
              "The simulated graph raises it: there a late reply is the machine's load, not the servo",
              low=0.0, high=10_000.0, read_only=True),
    ParamSpec("error_limit", 10, "consecutive failed cycles before the bus counts as lost", low=1, high=10_000,
              read_only=True),
)


def read_neutral_file(path: Path, ids: list[int]) -> list[int]:
    """Neutral ticks stored in ``path`` for ``ids``; ValueError says what is wrong with the file."""
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict) or data.get("ids") != ids:
        raise ValueError(f"{path} is not a neutral file for motor IDs {ids}")
    ticks = data.get("neutral_ticks")
    if not (isinstance(ticks, list) and len(ticks) == len(ids) and all(type(t) is int for t in ticks)):
        raise ValueError(f"{path}: neutral_ticks must be {len(ids)} integers, got {ticks!r}")
    return ticks


def write_neutral_file(path: Path, ids: list[int], ticks: list[int]) -> None:
    """Store the neutral ticks (atomic replace) so later starts can check the robot starts untwisted."""
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_name(path.name + ".tmp")
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    staging.write_text(f"# neutral ticks of the HSA motors, stored by dynamixel_driver at {stamp}\n"
                       + yaml.safe_dump({"ids": ids, "neutral_ticks": ticks}, default_flow_style=None))
    staging.replace(path)


class DynamixelDriver(LifecycleNode):
    """Writes the newest phi_cmd as clamped goal ticks and publishes the servos' present state, at ``rate``."""

    def __init__(self) -> None:
        super().__init__("dynamixel_driver")
        self._p: dict[str, Any] = declare(self, SPECS)
        guard_updates(self, SPECS, self._p.update)
        self._ids: list[int] = self._p["motor_ids"]
        self._phi_max = self._twist_limit()
        self._stored_neutral = self._configured_neutral()
        self._held = False  # every servo still had torque on at the first connection (a driver restart)
        self._uncalibrated: str | None = None  # why there is no trustworthy neutral (torque stays off), or None
        self._rejections = RejectionLog()
        self._bus: DynamixelBus | None = None
        self._map: MotorMap | None = None
        self._limits: MotorLimits | None = None
        self._sane: MotorLimits | None = None
        self._neutral: np.ndarray | None = None  # configured neutral ticks: the limits' reference
        self._cycle_timer: Timer | None = None
        self._reconnect_timer: Timer | None = None
        self._active = False
        self._link_up = False
        self._torque_on = False
        self._torque_wanted = False
        self._startup_checked = False
        self._torque_note = "not configured"
        self._last_bus_problem = ""
        self._last_error = ""
        self._latency = "not checked"
        self._hw_errors: dict[int, int] = {}
        self._alerts: frozenset[int] = frozenset()
        self._command: PlanarActuation | None = None
        self._command_time: float | None = None
        self._pending = False
        self._target: np.ndarray | None = None
        self._target_source = None
        self._limiter = GoalRateLimiter()  # the goal in force and the rate limit, on the node clock
        self._watchdog = "waiting for the first command"
        self._relaxed = False  # torque off by the watchdog (watchdog_action 'relax') until the next phi_cmd
        self._estop: str | None = None  # why the E-stop is engaged, None while released
        self._estop_since = 0.0
        self._last_reboot = "none"
        self._lost_at: float | None = None
        self._last_outage = "none"
        self._consecutive_failures = 0
        self._counts = dict.fromkeys(
            ("cycles", "writes", "reads", "commands", "rejected", "clamped", "ignored", "reconnect_attempts",
             "reconnects", "bus_losses", "port_errors", "comm_errors", "status_errors", "estops", "rate_limited",
             "reboots"),
            0)
        self._rate_base = (self._now(), dict(self._counts))
        self._fault_file = os.environ.get(FAULT_FILE_ENV) or None
        if self._fault_file:
            self.get_logger().warning(f"test hook armed: the control cycle raises while {self._fault_file} exists")

        options = qos.overridable()
        self._pub_states = self.create_publisher(JointState, "motor_states", qos.SENSOR,
                                                 qos_overriding_options=options)
        self._pub_phi = self.create_publisher(PlanarActuation, "phi_present", qos.SENSOR,
                                              qos_overriding_options=options)
        self._pub_goal = self.create_publisher(PlanarActuation, "motor_goal_stamp", qos.SENSOR,
                                               qos_overriding_options=options)
        self.create_subscription(PlanarActuation, "phi_cmd", self._on_command, qos.COMMAND,
                                 qos_overriding_options=options)
        self.create_service(SetBool, "set_torque", self._on_set_torque)
        self.create_service(Trigger, "reboot", lambda req, res: self._on_reboot(self._ids, res))
        for dxl_id in self._ids:
            self.create_service(Trigger, f"reboot_{dxl_id}", lambda req, res, i=dxl_id: self._on_reboot([i], res))
        self._pub_estop = self.create_publisher(Bool, "estop", qos.LATCHED)
        self._pub_estop.publish(Bool(data=False))
        self.create_service(Trigger, "estop", self._on_estop)
        self.create_service(Trigger, "clear_estop", self._on_clear_estop)
        # reliable, volatile, depth 10: matches any reliable publisher, and a quick True/False pair loses nothing
        self.create_subscription(Bool, "estop_request", self._on_estop_request, qos.INFO)
        diagnostics = Diagnostics(self, hardware_id=self._p["port"])
        diagnostics.add("bus", self._bus_report)
        diagnostics.add("servos", self._servo_report)
        diagnostics.add("control", self._control_report)
        diagnostics.add("estop", self._estop_report)
        if self._p["autostart"]:  # from the executor, so torque is never on outside the runner's shutdown guard
            self._autostart_timer: Timer | None = self.create_timer(0.0, self._autostart)

    def _now(self) -> float:
        """Node-clock time [s]: every timing decision uses it, so with use_sim_time it is simulated time."""
        return self.get_clock().now().nanoseconds * 1e-9

    def lockstep_ready(self) -> bool:
        """Lockstep: simulated time may start once the bus is connected, the driver active and torque on if wanted."""
        return self._active and self._link_up and (self._torque_on or not self._torque_wanted)

    def _autostart(self) -> None:
        """One-shot: configure and activate without a lifecycle manager."""
        if self._autostart_timer is None:
            return  # an event the EventsExecutor had queued before the timer was destroyed
        self.destroy_timer(self._autostart_timer)
        self._autostart_timer = None
        try:
            if self.trigger_configure() == SUCCESS:
                self.trigger_activate()
        except _rclpy.RCLError:
            if self.context.ok():
                raise  # otherwise a signal shut the context down mid-transition: the runner's hook follows

    # ------------------------------------------------------------------ start-up checks
    def _twist_limit(self) -> float:
        """φ_max [rad]: the parameter, or the smaller rod limit of the parameter set."""
        if self._p["phi_max"] > 0.0:
            return float(self._p["phi_max"])
        name = "params_file" if self._p["params_file"] else "material"
        try:
            params = load_params(self._p["params_file"] or self._p["material"])
        except ParameterError as exc:
            raise ParameterValidationError(f"parameter '{name}': {exc}") from exc
        return float(np.min(np.asarray(params.phi_max)))

    def _configured_neutral(self) -> list[int] | None:
        """Neutral ticks fixed before the bus is opened (param, read's reference, or an existing file), or None (the
        first start with neutral_source 'file': the calibration is written from the present positions)."""
        source, path = self._p["neutral_source"], self._p["neutral_file"]
        if source in ("param", "read"):
            return list(self._p["neutral_ticks"])
        if source == "file":
            if not path:
                raise ParameterValidationError("parameter 'neutral_file' must be set when neutral_source is 'file'")
            if Path(path).exists():
                try:
                    return read_neutral_file(Path(path), self._ids)
                except (OSError, ValueError, yaml.YAMLError) as exc:
                    raise ParameterValidationError(f"parameter 'neutral_file': {exc}") from exc
        return None

    def _set_neutral(self, ticks: list[int]) -> None:
        """Build the motor map, the absolute goal clamp and the wider 'sane position' range around the configured
        neutral ticks; a read neutral may later replace the map's zero (``_refine_map``), never these limits."""
        self._map = MotorMap(tuple(ticks), tuple(self._ids), rho=tuple(self._p["rho"]), h=tuple(self._p["h"]),
                             phi_max=self._phi_max, margin=self._p["goal_margin"])
        self._limits = MotorLimits.from_map(self._map)
        wider = dataclasses.replace(self._map, margin=self._p["goal_margin"] + self._p["neutral_tolerance"])
        self._sane = MotorLimits.from_map(wider)
        self._neutral = np.asarray(ticks, dtype=np.int64)

    def _refine_map(self) -> None:
        """neutral_source 'read': the present positions become the φ map's zero if they lie within neutral_tolerance
        of the configured neutral ticks; the goal limits stay where the configuration put them."""
        assert self._bus is not None and self._map is not None
        present = self._bus.read_positions().ticks
        ticks = [present[i] for i in self._ids]
        problem = accept_read_neutral(ticks, self._neutral, self._p["neutral_tolerance"])
        if problem is not None:
            self.get_logger().warning(f"{problem}: the φ map keeps the configured neutral ticks")
            return
        self._map = dataclasses.replace(self._map, neutral_ticks=tuple(ticks))
        self.get_logger().info(f"φ map zero read from the servos: {ticks} (limits on {self._neutral.tolist()})")

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Create the bus and try to open it; while it is absent the reconnect timer keeps trying."""
        self._bus = DynamixelBus(self._p["port"], self._p["baudrate"], self._ids,
                                 min_packet_timeout_ms=self._p["packet_timeout"])
        self._map = self._limits = self._sane = None
        if self._stored_neutral is not None:
            self._set_neutral(self._stored_neutral)
        self._startup_checked = self._stored_neutral is None  # a first calibration is the present positions
        self._held = False
        self._uncalibrated = None
        self._torque_note = "inactive"
        # the bus is hardware: reconnection runs on the steady clock, also while simulated time stands still
        self._reconnect_timer = lockstep.wall_timer(self, self._p["reconnect_period"], self._reconnect)
        self._connect()
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable torque holding the present position (if sane) and start the control cycle."""
        self._active = True
        self._torque_wanted = True
        self._relaxed = False
        self._clear_command()
        if self._link_up and self._estop is None:
            self._enable_torque()
        self._cycle_timer = self.create_timer(1.0 / self._p["rate"], self._cycle)
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle and switch torque off."""
        self._stop_cycle()
        self._disable_torque("deactivated")
        return SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Torque off and close the bus."""
        self._release("cleaned up")
        return SUCCESS

    def on_shutdown(self, state: LifecycleState | None = None) -> TransitionCallbackReturn:
        """Torque off and close the bus: the lifecycle transition, and the runner's exit hook (signals, exceptions)."""
        self._release("shut down")
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: torque off, close the bus, go back to unconfigured."""
        self.get_logger().error("lifecycle transition failed: torque off, bus closed")
        self._release("error")
        return SUCCESS

    def _stop_cycle(self) -> None:
        self._active = False
        self._torque_wanted = False
        self._relaxed = False
        if self._cycle_timer is not None:
            self.destroy_timer(self._cycle_timer)
            self._cycle_timer = None

    def _release(self, reason: str) -> None:
        """Switch torque off (best effort, no ROS needed), close the port and stop the timers; idempotent."""
        self._disable_torque(reason)
        if self._bus is not None:
            self._bus.close()
        self._link_up = False
        self._stop_cycle()
        if self._reconnect_timer is not None:
            self.destroy_timer(self._reconnect_timer)
            self._reconnect_timer = None

    # ------------------------------------------------------------------ connection and torque
    def _connect(self) -> None:
        """Open the bus, configure the servos (torque off, return delay, extended position mode), fix neutrals."""
        assert self._bus is not None
        try:
            self._bus.close()
            self._bus.open()
            if self._map is None or not self._startup_checked:  # before configure() turns torque off: still held?
                self._held = all(self._bus.read_register(i, ADDR_TORQUE_ENABLE, 1) == 1 for i in self._ids)
            self._bus.configure(return_delay=self._p["return_delay"])
            if self._map is None:
                self._adopt_present_as_neutral()
            elif self._p["neutral_source"] == "read" and not self._startup_checked:
                self._refine_map()
        except BusError as exc:
            self._count_error(exc)
            self._bus.close()
            if str(exc) != self._last_bus_problem:
                self.get_logger().warning(f"bus not ready ({exc}); retrying every {self._p['reconnect_period']} s")
                self._last_bus_problem = str(exc)
            return
        self._link_up = True
        self._last_bus_problem = ""
        self._consecutive_failures = 0
        if self._lost_at is not None:
            self._counts["reconnects"] += 1
            self._last_outage = f"{self._now() - self._lost_at:.3f} s"
            self._lost_at = None
            self.get_logger().info(f"bus reconnected after {self._last_outage}")
        latency = self._bus.latency_timer()
        self._latency = latency.describe()
        if latency.slow:
            self.get_logger().warning(self._latency)
        self.get_logger().info(f"bus open: {self._p['port']} at {self._p['baudrate']} baud, IDs {self._ids}")
        if self._active and self._torque_wanted and not self._relaxed and self._estop is None:
            self._enable_torque()

    def _adopt_present_as_neutral(self) -> None:
        """First start with a missing neutral file: the present positions become the stored calibration — unless the
        servos were held (a pose someone commanded, not the rest pose): then nothing is stored and torque stays off."""
        assert self._bus is not None
        present = self._bus.read_positions().ticks
        ticks = [present[i] for i in self._ids]
        self._set_neutral(ticks)  # also gives the state topics their zero while uncalibrated
        path = self._p["neutral_file"]
        if self._held:
            self._uncalibrated = (f"no neutral file {path} and the servos were held at start (not necessarily at "
                                  "rest): switch their torque off or power-cycle them at rest, then restart")
            self.get_logger().error(f"not calibrating: {self._uncalibrated}")
            return
        try:
            write_neutral_file(Path(path), self._ids, ticks)
        except OSError as exc:
            self.get_logger().error(f"cannot store neutral ticks {ticks} in {path}: {exc}")
            return
        self._stored_neutral = ticks
        self.get_logger().info(f"stored neutral ticks {ticks} in {path}")

    def _reconnect(self) -> None:
        """Reconnect timer: reopen the bus while it is down."""
        if not self._link_up:
            self._counts["reconnect_attempts"] += 1
            self._connect()

    def _position_problem(self, ticks: np.ndarray) -> str | None:
        """Why torque must not be enabled at these present positions, or None."""
        assert self._map is not None and self._sane is not None and self._neutral is not None
        if self._uncalibrated is not None:
            return self._uncalibrated
        if not self._startup_checked:
            problem = neutral_check(ticks_to_angles(ticks, self._neutral), self._p["neutral_tolerance"], self._held)
            if problem is not None:
                return problem
            if self._held:
                self.get_logger().warning("servos still held at start (driver restart): keeping their pose within "
                                          f"the limits of the configured neutral ticks {self._neutral.tolist()}")
            self._startup_checked = True
        inside = self._sane.contains(ticks)
        if not np.all(inside):
            outside = [i for i, ok in zip(self._ids, inside) if not ok]
            return f"present positions of IDs {outside} are outside the goal limits (servo power-cycled or turned?)"
        return None

    def _enable_torque(self) -> str | None:
        """Torque on holding the present positions if they are sane; returns why not otherwise."""
        assert self._bus is not None
        try:
            reading = self._bus.read_positions()
            if reading.alerts:
                self._hw_errors = {i: b for i, b in self._bus.read_hardware_errors().items() if b}
            self._alerts = reading.alerts
            ticks = self._present_ticks(reading.ticks)
            problem = self._hardware_problem() or self._position_problem(ticks)
            if problem is None:
                self._bus.enable_torque()
        except BusError as exc:
            self._count_error(exc)
            self._bus.disable_torque(verify=False)  # servos enabled before the failure must not stay on
            problem = f"torque-on failed: {exc}"
        if problem is not None:
            if problem != self._torque_note:
                self.get_logger().error(f"torque stays off: {problem}")
            self._torque_note = problem
            return problem
        self._torque_on = True
        self._torque_note = "on"
        self._limiter.reset(ticks)
        self._clear_command()
        self.get_logger().info("torque on, holding the present positions")
        return None

    def _disable_torque(self, reason: str) -> frozenset[int]:
        """Best-effort torque off (one sync write, then read back); returns and logs the IDs that did not confirm."""
        was_on = self._torque_on
        self._torque_on = False
        self._torque_note = f"off ({reason})"
        if self._bus is None or not self._bus.is_open:
            return frozenset(self._ids)
        unconfirmed = self._bus.disable_torque()
        if unconfirmed:  # once more after a pause, so a half-finished exchange (e.g. cut by a signal) has died out
            time.sleep(0.1)
            unconfirmed = self._bus.disable_torque()
        if unconfirmed:
            self.get_logger().error(f"torque off ({reason}) not confirmed by IDs {sorted(unconfirmed)}")
        elif was_on:
            self.get_logger().info(f"torque off ({reason})")
        return unconfirmed

    def _hardware_problem(self) -> str | None:
        if not self._hw_errors:
            return None
        described = {i: describe_hardware_error(b) for i, b in self._hw_errors.items()}
        return f"hardware error {described}: call reboot (or reboot_<id>), or power-cycle the servo"

    def _lose_link(self, exc: BusError) -> None:
        """The bus stopped answering: torque off where still possible, close, let the reconnect timer retry."""
        assert self._bus is not None
        self.get_logger().error(f"bus lost ({exc}); torque off, reconnecting every {self._p['reconnect_period']} s")
        self._last_bus_problem = str(exc)
        self._disable_torque("bus lost")
        self._bus.close()
        self._link_up = False
        self._lost_at = self._now()
        self._counts["bus_losses"] += 1

    def _count_error(self, exc: BusError) -> None:
        self._last_error = str(exc)
        kind = ("port_errors" if isinstance(exc, PortError) else "comm_errors" if isinstance(exc, CommError)
                else "status_errors" if isinstance(exc, ServoStatusError) else "comm_errors")
        self._counts[kind] += 1

    # ------------------------------------------------------------------ commands and service
    def _on_command(self, msg: PlanarActuation) -> None:
        """Keep the newest finite command (ignored while the E-stop is engaged); the cycle writes it."""
        if not np.all(np.isfinite(msg.phi)):
            self._counts["rejected"] += 1
            self._log_rejection("rejected", f"non-finite phi {list(msg.phi)}")
            return
        if self._estop is not None:
            self._counts["ignored"] += 1
            return
        self._counts["commands"] += 1
        if self._relaxed and self._torque_wanted and self._active and self._link_up:
            self._wake_from_relax()
        self._command, self._command_time, self._pending = msg, self._now(), True
        if self._p["write_on_command"] and self._active and self._link_up:
            try:  # the goal leaves now instead of waiting up to one read period (compute-path latency)
                self._write_goal()
            except BusError as exc:
                self._count_error(exc)  # the next cycle retries the write and handles a lost link

    def _log_rejection(self, kind: str, detail: str) -> None:
        """WARN about a rejected or clipped command, throttled by RejectionLog (the counters count every one)."""
        line = self._rejections.record(kind, detail, self._now())
        if line is not None:
            self.get_logger().warning(line)

    def _clear_command(self) -> None:
        self._command = self._command_time = self._target = None
        self._pending = False
        self._watchdog = "waiting for the first command"

    def _wake_from_relax(self) -> None:
        """A phi_cmd after the watchdog relaxed the motors: torque on again (holding the present positions) if safe."""
        if self._enable_torque() is None:
            self._relaxed = False
            self.get_logger().info("phi_cmd resumed: torque on again after the watchdog relaxed the motors")

    def _on_set_torque(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """Torque on (if active, connected, not E-stopped and sane) or off."""
        if not request.data:
            self._torque_wanted = False
            self._disable_torque("set_torque service")
            response.success, response.message = True, "torque off"
        elif self._estop is not None:
            response.success, response.message = False, f"E-stop engaged ({self._estop}): call clear_estop"
        elif not self._active:
            response.success, response.message = False, "node is not active"
        elif self._torque_on:
            response.success, response.message = True, "torque already on"
        elif not self._link_up:
            response.success, response.message = False, f"bus not connected: {self._last_bus_problem}"
        else:
            problem = self._enable_torque()
            self._torque_wanted = problem is None
            self._relaxed = False
            response.success, response.message = problem is None, problem or "torque on"
        return response

    def _on_reboot(self, ids: list[int], response: Trigger.Response) -> Trigger.Response:
        """Services ``reboot`` (all servos) and ``reboot_<id>``: Protocol 2.0 REBOOT to clear a latched hardware error.

        Refused while torque is on and fresh commands are being tracked. Otherwise torque goes off for every servo,
        the servos are rebooted, waited for, configured again (torque off, Return Delay Time, Operating Mode) and
        their hardware errors and present positions re-read and re-checked against the configured limits; torque
        stays off until ``set_torque(true)``, which checks them again.
        """
        problem = reboot_refusal(self._active, self._link_up, self._torque_on, self._watchdog == "fresh")
        if problem is not None:
            response.success, response.message = False, f"reboot refused: {problem}"
            return response
        assert self._bus is not None
        self._torque_wanted, self._relaxed = False, False
        self._disable_torque(f"reboot of IDs {ids}")
        self._clear_command()
        began = time.monotonic()
        try:
            for dxl_id in ids:
                self._bus.reboot(dxl_id)
            self._bus.wait_answering(ids, REBOOT_WAIT_S)
            self._bus.configure(return_delay=self._p["return_delay"])  # RAM defaults: torque off; EEPROM checked
            reading = self._bus.read_positions()
            errors = {i: b for i, b in self._bus.read_hardware_errors().items() if b}
        except BusError as exc:
            self._count_error(exc)
            self._torque_note = f"off (reboot of IDs {ids} failed: {exc})"
            self.get_logger().error(self._torque_note)
            response.success, response.message = False, f"reboot of IDs {ids} failed: {exc}"
            return response
        took = time.monotonic() - began
        self._counts["reboots"] += 1
        self._hw_errors, self._alerts = errors, reading.alerts
        problem = self._hardware_problem() or self._position_problem(self._present_ticks(reading.ticks))
        if problem is not None and not errors:
            problem = f"{problem}; a reboot resets the multi-turn count (present position within one turn)"
        self._last_reboot = f"IDs {ids} in {took * 1e3:.1f} ms: " + (problem or "ready for set_torque(true)")
        self._torque_note = f"off (rebooted IDs {ids}{': ' + problem if problem else ''})"
        if problem is not None:
            self.get_logger().error(f"rebooted IDs {ids}; torque stays off: {problem}")
        else:
            self.get_logger().warning(f"rebooted IDs {ids} in {took * 1e3:.1f} ms: hardware errors cleared, present "
                                      "positions within the limits; torque off until set_torque(true)")
        response.success = problem is None
        response.message = (f"rebooted IDs {ids}; " + (f"torque stays off: {problem}" if problem else
                            "hardware errors cleared, positions within the limits: call set_torque(true)"))
        return response

    # ------------------------------------------------------------------ emergency stop
    def _engage_estop(self, reason: str) -> str:
        """Torque off at once, stop writing goals and ignore phi_cmd until clear_estop; returns the torque outcome."""
        unconfirmed = self._disable_torque("E-stop")
        self._clear_command()
        if unconfirmed:
            outcome = (f"torque off not confirmed by IDs {sorted(unconfirmed)}" if self._link_up
                       else f"bus not connected ({self._last_bus_problem}): torque off not possible")
        else:
            outcome = "torque off confirmed"
        if self._estop is None:
            self._estop, self._estop_since = reason, self._now()
            self._counts["estops"] += 1
            self._pub_estop.publish(Bool(data=True))
            self.get_logger().error(f"E-stop engaged ({reason}): {outcome}; phi_cmd ignored until clear_estop")
        return outcome

    def _on_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Service ``estop``: engage (idempotent); success means the stop is latched, the message gives torque."""
        response.success, response.message = True, f"E-stop engaged: {self._engage_estop('estop service')}"
        return response

    def _on_estop_request(self, msg: Bool) -> None:
        """Topic ``estop_request``: True engages the E-stop; False is ignored (only clear_estop releases it)."""
        if msg.data:
            self._engage_estop("estop_request topic")

    def _on_clear_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Service ``clear_estop``: release only if torque can be re-enabled safely (same checks as a reconnect)."""
        if self._estop is None:
            response.success, response.message = True, "E-stop was not engaged"
            return response
        if not self._active:
            problem = "node is not active"
        elif not self._link_up:
            problem = f"bus not connected: {self._last_bus_problem}"
        else:
            problem = self._enable_torque()
        if problem is not None:
            response.success, response.message = False, f"E-stop stays engaged: {problem}"
            return response
        self._estop = None
        self._torque_wanted, self._relaxed = True, False
        self._pub_estop.publish(Bool(data=False))
        self.get_logger().warning("E-stop cleared: torque on, holding the present positions")
        response.success, response.message = True, "E-stop cleared, torque on"
        return response

    # ------------------------------------------------------------------ control cycle
    def _cycle(self) -> None:
        """One control cycle: at most one sync write of the newest command, then one sync read."""
        now = self._now()
        self._counts["cycles"] += 1
        if self._fault_file and os.path.exists(self._fault_file):
            raise InjectedFault(f"injected by {FAULT_FILE_ENV}={self._fault_file}")
        if not self._link_up:
            return
        self._update_watchdog(now)
        try:
            self._write_goal()
            reading = self._bus.read_positions()
            self._counts["reads"] += 1
            self._publish_state(reading.ticks, reading.velocities)
            if reading.alerts != self._alerts:
                self._on_alerts(reading.alerts)
        except BusError as exc:
            self._count_error(exc)
            self._consecutive_failures += 1
            if isinstance(exc, PortError) or self._consecutive_failures >= self._p["error_limit"]:
                self._lose_link(exc)
            return
        self._consecutive_failures = 0

    def _update_watchdog(self, now: float) -> None:
        """Command watchdog: no fresh phi_cmd for > command_timeout → hold the last goal or relax (log once)."""
        timeout = self._p["command_timeout"]
        if self._command_time is None:
            return
        if timeout > 0.0 and now - self._command_time > timeout:
            if self._watchdog != "expired":
                relax = self._p["watchdog_action"] == "relax"
                self.get_logger().warning(f"no phi_cmd for > {timeout} s: "
                                          + ("relaxing (torque off)" if relax else "holding the last goal"))
                if relax and self._torque_on:
                    self._relaxed = True
                    self._disable_torque("watchdog: no phi_cmd")
            self._watchdog, self._target, self._pending = "expired", None, False
        elif self._watchdog != "fresh":
            if self._watchdog == "expired":
                self.get_logger().info("phi_cmd resumed")
            self._watchdog = "fresh"

    def _write_goal(self) -> None:
        """Sync-write the clamped (and rate-limited) goal of the newest command, if there is something to write."""
        if not self._torque_on:
            self._pending = False
            return
        assert self._map is not None and self._limits is not None and self._bus is not None
        fresh = self._pending
        if fresh:
            phi = np.asarray(self._command.phi)
            clipped = np.clip(phi, 0.0, self._phi_max)
            self._target, clamped = self._limits.clamp(self._map.goal_ticks(clipped))
            if np.any(clipped != phi) or np.any(clamped):
                self._counts["clamped"] += 1
                self._log_rejection("clipped", f"phi {np.round(phi, 4).tolist()} rad outside [0, {self._phi_max:.4f}]"
                                    if np.any(clipped != phi) else f"goal ticks clamped to the limits for phi {phi}")
            self._target_source, self._pending = self._command.source_stamp, False
        if self._target is None:
            return
        now = self._now()  # max_goal_rate x the time since the goal of the last earlier instant, at most a period
        goal = self._limiter.limited(self._target, now, self._p["max_goal_rate"], 1.0 / self._p["rate"],
                                     lambda g: self._limits.clamp(g)[0])
        self._counts["rate_limited"] += fresh and not np.array_equal(goal, self._target)
        if not fresh and np.array_equal(goal, self._limiter.goal):
            return
        self._bus.write_goals({i: int(t) for i, t in zip(self._ids, goal)})
        self._limiter.written(goal, now)
        self._counts["writes"] += 1
        msg = PlanarActuation(phi=self._map.present_twists(goal), source_stamp=self._target_source)
        # a goal cannot leave before the command it came from: under simulated time a phi_cmd may be taken before
        # this node has seen the /clock of the tick that sent it
        issued = Time.from_msg(self._command.header.stamp).nanoseconds if self._command is not None else 0
        msg.header.stamp = Time(nanoseconds=max(self.get_clock().now().nanoseconds, issued)).to_msg()
        self._pub_goal.publish(msg)

    def _publish_state(self, ticks_by_id: dict[int, int], velocities: dict[int, int]) -> None:
        assert self._map is not None
        ticks = self._present_ticks(ticks_by_id)
        stamp = self.get_clock().now().to_msg()
        joints = JointState(name=[f"motor_{i}" for i in self._ids],
                            position=ticks_to_angles(ticks, self._map.neutral_ticks).tolist(),
                            velocity=[velocities[i] * VELOCITY_UNIT_RAD_S for i in self._ids])
        joints.header.stamp = stamp
        self._pub_states.publish(joints)
        phi = PlanarActuation(phi=self._map.present_twists(ticks))
        phi.header.stamp = stamp
        self._pub_phi.publish(phi)

    def _present_ticks(self, ticks_by_id: dict[int, int]) -> np.ndarray:
        return np.array([ticks_by_id[i] for i in self._ids], dtype=np.int64)

    def _on_alerts(self, alerts: frozenset[int]) -> None:
        """The set of alerting servos changed: read their Hardware Error Status; on a new error, torque off for all."""
        assert self._bus is not None
        errors = {i: b for i, b in self._bus.read_hardware_errors().items() if b} if alerts else {}
        self._alerts = alerts
        if errors == self._hw_errors:
            return
        self._hw_errors = errors
        if errors:
            self._torque_wanted = False
            self._disable_torque("hardware error")
            self._torque_note = self._hardware_problem() or ""
            self.get_logger().error(f"torque off: {self._torque_note}")
        else:
            self.get_logger().info("hardware errors cleared")

    # ------------------------------------------------------------------ diagnostics
    def _bus_report(self) -> Report:
        values = {"port": self._p["port"], "baudrate": self._p["baudrate"], "latency_timer": self._latency,
                  **{k: self._counts[k] for k in ("bus_losses", "reconnect_attempts", "reconnects", "port_errors",
                                                   "comm_errors", "status_errors")},
                  "last_outage": self._last_outage, "consecutive_failures": self._consecutive_failures,
                  "last_error": self._last_error}
        if self._bus is None:
            return Report(WARN, "not configured", values)
        if not self._link_up:
            return Report(ERROR, f"disconnected: {self._last_bus_problem}", values)
        return Report(WARN if self._consecutive_failures else OK, "connected", values)

    def _servo_report(self) -> Report:
        values = {"torque": self._torque_note, "neutral_ticks": list(self._map.neutral_ticks) if self._map else [],
                  "neutral_source": self._p["neutral_source"],
                  "goal_limits": [[int(lo), int(hi)] for lo, hi in zip(self._limits.lower, self._limits.upper)]
                  if self._limits else [], "held_at_start": self._held, "reboots": self._counts["reboots"],
                  "last_reboot": self._last_reboot,
                  **{f"hardware_error_{i}": describe_hardware_error(self._hw_errors.get(i, 0)) for i in self._ids}}
        if self._hw_errors:
            return Report(ERROR, self._hardware_problem() or "", values)
        if self._estop is not None:
            return Report(ERROR, f"torque off: E-stop engaged ({self._estop})", values)
        if self._active and not self._torque_on:
            unwanted = self._torque_wanted and not self._relaxed
            return Report(ERROR if unwanted else WARN, f"torque off: {self._torque_note}", values)
        return Report(OK, f"torque {'on' if self._torque_on else 'off'}", values)

    def _control_report(self) -> Report:
        now = self._now()
        since, base = self._rate_base
        elapsed = max(now - since, 1e-9)
        rates = {f"{k}_per_s": round((self._counts[k] - base[k]) / elapsed, 1) for k in ("cycles", "writes", "reads")}
        self._rate_base = (now, dict(self._counts))
        age = "none" if self._command_time is None else f"{now - self._command_time:.3f} s"
        watchdog = f"{self._watchdog} ({'relaxed' if self._relaxed else self._p['watchdog_action']})" \
            if self._watchdog == "expired" else self._watchdog
        values = {**rates, **{k: self._counts[k] for k in ("commands", "rejected", "clamped", "rate_limited",
                                                            "ignored")},
                  "watchdog": watchdog, "command_age": age, "command_timeout": self._p["command_timeout"],
                  "max_goal_rate": self._p["max_goal_rate"], "phi_max": self._phi_max}
        level = WARN if self._watchdog == "expired" else OK
        return Report(level, f"watchdog: {watchdog}", values)

    def _estop_report(self) -> Report:
        values = {"engaged": self._estop is not None, "reason": self._estop or "",
                  "engaged_for": f"{self._now() - self._estop_since:.1f} s" if self._estop else "",
                  "estops": self._counts["estops"], "ignored_commands": self._counts["ignored"]}
        if self._estop is not None:
            return Report(ERROR, f"E-stop engaged ({self._estop}): call clear_estop", values)
        return Report(OK, "released", values)


def main() -> None:
    """Console entry point ``dynamixel_driver``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(DynamixelDriver, "dynamixel_driver"))

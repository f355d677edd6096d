"""The dynamixel_driver's bus side: connect and reconnect, neutral ticks, torque on/off, link loss, hardware errors
and reboots — the I/O around the decisions of `hsa_core.servo_supervision.ServoSupervisor` (no ROS: the node passes
its logger and node clock in).

Torque-on holds the present positions (goal := present, so nothing jumps); torque-off is best effort with plain
serial I/O, verified and repeated once after 0.1 s (usable after the ROS context is gone: the runner's exit hook).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hsa_common.model_params import load_model, load_wiring_param
from hsa_core.actuation import MotorLimits, MotorMap, accept_read_neutral
from hsa_core.servo_supervision import Alert, Answer, ServoSupervisor
from hsa_dynamixel_driver.bus import (
    ADDR_TORQUE_ENABLE,
    BusError,
    CommError,
    DynamixelBus,
    PortError,
    ServoStatusError,
    describe_hardware_error,
)
from hsa_dynamixel_driver.goals import GoalPipeline
from hsa_dynamixel_driver.neutral import configured_neutral, write_neutral_file

REBOOT_WAIT_S = 2.0  # wall-clock wait for rebooted servos to answer a ping again (bus-level, like the SDK timeouts)
COUNTERS = ("cycles", "writes", "reads", "commands", "rejected", "clamped", "ignored", "reconnect_attempts",
            "reconnects", "bus_losses", "port_errors", "comm_errors", "status_errors", "estops", "rate_limited",
            "reboots")


class Servos:
    """The bus, the φ map and goal limits, and the supervisor they report to; ``p`` are the node's parameters."""

    def __init__(self, p: dict[str, Any], logger: Any, now: Callable[[], float]) -> None:
        """Load the model and wiring, fix the configured neutral (a refused parameter raises ParameterValidationError)."""
        self._p, self._log, self._now = p, logger, now
        self.wiring = load_wiring_param(p["wiring_file"])  # motor IDs, rods and rod signs: the robot's wiring file
        self._model = load_model(p)  # the rods' handedness and twist limit
        self.limit = self._model.phi_limit  # the φ limit; the motor map's goal clamp is its `motor` bound
        self.ids: list[int] = list(self.wiring.motor_ids)
        self.stored_neutral = configured_neutral(p, self.ids, self.wiring.neutral_ticks)
        self.sup = ServoSupervisor(tuple(self.ids), p["error_limit"], p["neutral_tolerance"],
                                   describe_hardware_error, p["torque_retry_period"], p["torque_retry_max"])
        self.goals = GoalPipeline()
        self.counts = dict.fromkeys(COUNTERS, 0)
        self.bus: DynamixelBus | None = None
        self.map: MotorMap | None = None
        self.limits: MotorLimits | None = None
        self.latency = "not checked"
        self.last_error = ""
        self.last_reboot = "none"

    def present_ticks(self, ticks_by_id: dict[int, int]) -> np.ndarray:
        """Ticks in ``ids`` order."""
        return np.array([ticks_by_id[i] for i in self.ids], dtype=np.int64)

    def clear_command(self) -> None:
        """Discard the command, its target and the watchdog's arming."""
        self.goals.clear()
        self.sup.clear_command()

    # ------------------------------------------------------------------ neutral ticks
    def _set_neutral(self, ticks: list[int]) -> None:
        """Build the motor map, the absolute goal clamp and the sane range around the configured neutral ticks; a
        read neutral may later replace the map's zero (``_refine_map``), never these limits."""
        self.map = self.wiring.motor_map(self._model, neutral_ticks=tuple(ticks), margin=self._p["goal_margin"])
        self.limits = MotorLimits.from_map(self.map)
        self.sup.calibrate(self.map)

    def _refine_map(self) -> None:
        """neutral_source 'read': the present positions become the φ map's zero if they lie within neutral_tolerance
        of the configured neutral ticks; the goal limits stay where the configuration put them."""
        assert self.bus is not None and self.map is not None and self.sup.neutral is not None
        ticks = self.present_ticks(self.bus.read_positions().ticks).tolist()
        problem = accept_read_neutral(ticks, self.sup.neutral, self._p["neutral_tolerance"])
        if problem is not None:
            self._log.warning(f"{problem}: the φ map keeps the configured neutral ticks")
            return
        self.map = dataclasses.replace(self.map, neutral_ticks=tuple(ticks))
        self._log.info(f"φ map zero read from the servos: {ticks} (limits on {self.sup.neutral.tolist()})")

    def _adopt_present_as_neutral(self) -> None:
        """First start with a missing neutral file: the present positions become the stored calibration, unless the
        supervisor refuses them (servos held at start): then nothing is stored and torque stays off."""
        assert self.bus is not None
        ticks = self.present_ticks(self.bus.read_positions().ticks).tolist()
        self._set_neutral(ticks)  # also gives the state topics their zero while uncalibrated
        path = self._p["neutral_file"]
        problem = self.sup.first_calibration(path)
        if problem is not None:
            self._log.error(f"not calibrating: {problem}")
            return
        try:
            write_neutral_file(Path(path), self.ids, ticks)
        except OSError as exc:
            self._log.error(f"cannot store neutral ticks {ticks} in {path}: {exc}")
            return
        self.stored_neutral = ticks
        self._log.info(f"stored neutral ticks {ticks} in {path}")

    # ------------------------------------------------------------------ connection
    def configure(self) -> None:
        """Create the bus (not yet opened) and fix the configured neutral, if there is one."""
        self.bus = DynamixelBus(self._p["port"], self._p["baudrate"], self.ids,
                                min_packet_timeout_ms=self._p["packet_timeout"])
        self.map = self.limits = None
        self.sup.configured(self.stored_neutral is not None)
        if self.stored_neutral is not None:
            self._set_neutral(self.stored_neutral)

    def connect(self) -> None:
        """Open the bus, configure the servos (torque off, return delay, extended position mode), fix neutrals; then
        torque on if it is due."""
        assert self.bus is not None
        try:
            self.bus.close()
            self.bus.open()
            if self.sup.needs_held_check():  # before configure() turns torque off: still held?
                self.sup.held = all(self.bus.read_register(i, ADDR_TORQUE_ENABLE, 1) == 1 for i in self.ids)
            self.bus.configure(return_delay=self._p["return_delay"])
            if self.map is None:
                self._adopt_present_as_neutral()
            elif self._p["neutral_source"] == "read" and not self.sup.startup_checked:
                self._refine_map()
        except BusError as exc:
            self.count_error(exc)
            self.bus.close()
            if self.sup.connect_failed(str(exc)):
                self._log.warning(f"bus not ready ({exc}); retrying every {self._p['reconnect_period']} s")
            return
        outage = self.sup.connected(self._now())
        if outage is not None:
            self.counts["reconnects"] += 1
            self._log.info(f"bus reconnected after {outage:.3f} s")
        latency = self.bus.latency_timer()
        self.latency = latency.describe()
        if latency.slow:
            self._log.warning(self.latency)
        self._log.info(f"bus open: {self._p['port']} at {self._p['baudrate']} baud, IDs {self.ids}")
        if self.sup.torque_due():
            self.enable_torque()

    def reconnect(self) -> None:
        """Reconnect timer: reopen the bus while it is down."""
        if not self.sup.link_up:
            self.counts["reconnect_attempts"] += 1
            self.connect()

    def lose_link(self, exc: BusError) -> None:
        """The bus stopped answering: torque off where still possible, close, let the reconnect timer retry."""
        assert self.bus is not None
        self._log.error(f"bus lost ({exc}); torque off, reconnecting every {self._p['reconnect_period']} s")
        self.disable_torque("bus lost")
        self.bus.close()
        self.sup.link_lost(str(exc), self._now())
        self.counts["bus_losses"] += 1

    def release(self, reason: str) -> None:
        """Switch torque off (best effort, no ROS needed) and close the port; idempotent."""
        self.disable_torque(reason)
        if self.bus is not None:
            self.bus.close()
        self.sup.released()

    def count_error(self, exc: BusError) -> None:
        """Count a bus error by kind and keep its text for diagnostics."""
        self.last_error = str(exc)
        kind = ("port_errors" if isinstance(exc, PortError) else "comm_errors" if isinstance(exc, CommError)
                else "status_errors" if isinstance(exc, ServoStatusError) else "comm_errors")
        self.counts[kind] += 1

    # ------------------------------------------------------------------ torque
    def _checked(self, check: Callable[[], str | None]) -> str | None:
        """Run one of the supervisor's torque-on checks; warn once when it keeps the pose of servos held at start."""
        checked = self.sup.startup_checked
        problem = check()
        if not checked and self.sup.startup_checked and self.sup.held:
            self._log.warning("servos still held at start (driver restart): keeping their pose within the limits "
                              f"of the configured neutral ticks {self.sup.neutral.tolist()}")
        return problem

    def enable_torque(self) -> str | None:
        """Torque on holding the present positions if the supervisor allows it; returns why not otherwise. A refusal
        by the checks stays until asked again; a failure on the bus is retried with backoff while torque is due."""
        assert self.bus is not None
        try:
            reading = self.bus.read_positions()
            errors = self._hardware_errors() if reading.alerts else None
            ticks = self.present_ticks(reading.ticks)
            problem = self._checked(lambda: self.sup.torque_on_problem(ticks, reading.alerts, errors))
            if problem is None:
                self.bus.enable_torque()
        except BusError as exc:
            self.count_error(exc)
            self.bus.disable_torque(verify=False)  # servos enabled before the failure must not stay on
            problem = f"torque-on failed: {exc}"
            delay = self.sup.torque_failed(problem, self._now())
            retry = f"; retrying in {delay:.3g} s" if delay is not None else ""
            self._log.error(f"torque stays off: {problem}{retry}")
            return problem
        if problem is not None:
            if self.sup.torque_refused(problem):
                self._log.error(f"torque stays off: {problem}")
            return problem
        failures = self.sup.torque_enabled()
        self.goals.limiter.reset(ticks)
        self.clear_command()
        after = f" (after {failures} failed torque-on attempts)" if failures else ""
        self._log.info(f"torque on, holding the present positions{after}")
        return None

    def disable_torque(self, reason: str) -> frozenset[int]:
        """Best-effort torque off (one sync write, then read back); returns and logs the IDs that did not confirm."""
        was_on = self.sup.torque_disabled(reason)
        if self.bus is None or not self.bus.is_open:
            return frozenset(self.ids)
        unconfirmed = self.bus.disable_torque()
        if unconfirmed:  # once more after a pause, so a half-finished exchange (e.g. cut by a signal) has died out
            time.sleep(0.1)
            unconfirmed = self.bus.disable_torque()
        if unconfirmed:
            self._log.error(f"torque off ({reason}) not confirmed by IDs {sorted(unconfirmed)}")
        elif was_on:
            self._log.info(f"torque off ({reason})")
        return unconfirmed

    def _hardware_errors(self) -> dict[int, int]:
        """Hardware Error Status of the servos that report one (nonzero bits only), read from the bus."""
        assert self.bus is not None
        return {i: b for i, b in self.bus.read_hardware_errors().items() if b}

    def alerts(self, alerts: frozenset[int]) -> None:
        """The set of alerting servos changed: read their Hardware Error Status; on a new error, torque off for all."""
        assert self.bus is not None
        errors = self._hardware_errors() if alerts else {}
        event = self.sup.hardware_errors(alerts, errors)
        if event is Alert.FAULT:
            self.disable_torque("hardware error")
            problem = self.sup.hardware_problem() or ""
            self.sup.torque_refused(problem)
            self._log.error(f"torque off: {problem}")
        elif event is Alert.CLEARED:
            self._log.info("hardware errors cleared")

    def reboot(self, ids: list[int]) -> Answer:
        """Protocol 2.0 REBOOT of ``ids`` (torque off for every servo first), then configure, re-read the hardware
        errors and present positions and re-check them; torque stays off until ``set_torque(true)``."""
        problem = self.sup.reboot_refusal()
        if problem is not None:
            return Answer(False, f"reboot refused: {problem}")
        assert self.bus is not None
        self.sup.reboot_started()
        self.disable_torque(f"reboot of IDs {ids}")
        self.clear_command()
        began = time.monotonic()
        try:
            for dxl_id in ids:
                self.bus.reboot(dxl_id)
            self.bus.wait_answering(ids, REBOOT_WAIT_S)
            self.bus.configure(return_delay=self._p["return_delay"])  # RAM defaults: torque off; EEPROM checked
            reading = self.bus.read_positions()
            errors = self._hardware_errors()
        except BusError as exc:
            self.count_error(exc)
            self.sup.torque_refused(f"off (reboot of IDs {ids} failed: {exc})")
            self._log.error(self.sup.note)
            return Answer(False, f"reboot of IDs {ids} failed: {exc}")
        took = time.monotonic() - began
        self.counts["reboots"] += 1
        ticks = self.present_ticks(reading.ticks)
        problem = self._checked(lambda: self.sup.rebooted(ticks, reading.alerts, errors))
        self.last_reboot = f"IDs {ids} in {took * 1e3:.1f} ms: " + (problem or "ready for set_torque(true)")
        self.sup.torque_refused(f"off (rebooted IDs {ids}{': ' + problem if problem else ''})")
        if problem is not None:
            self._log.error(f"rebooted IDs {ids}; torque stays off: {problem}")
        else:
            self._log.warning(f"rebooted IDs {ids} in {took * 1e3:.1f} ms: hardware errors cleared, present "
                              "positions within the limits; torque off until set_torque(true)")
        return Answer(problem is None, f"rebooted IDs {ids}; " + (f"torque stays off: {problem}" if problem else
                      "hardware errors cleared, positions within the limits: call set_torque(true)"))

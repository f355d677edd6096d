"""The dynamixel_driver's bus side: connect and reconnect, neutral ticks, torque on/off, link loss,
hardware errors and reboots — the I/O around the decisions of
`hsa_core.driver.servo_supervision.ServoSupervisor` (no ROS: the node passes its logger and node
clock in).

Torque-on holds the present positions (goal := present, so nothing jumps); torque-off is best effort
with plain serial I/O, verified and repeated once after 0.1 s (usable after the ROS context is gone:
the runner's exit hook).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hsa_common.model_params import load_model, load_wiring_param
from hsa_core.driver.servo_supervision import Alert, Answer, ServoSupervisor, Verdict, WatchdogEvent
from hsa_core.model.actuation import MotorLimits, MotorMap, RejectionLog, accept_read_neutral
from hsa_dynamixel_driver.bus import (
    ADDR_TORQUE_ENABLE,
    BusError,
    CommError,
    DynamixelBus,
    PortError,
    PositionReading,
    ServoStatusError,
    describe_hardware_error,
)
from hsa_dynamixel_driver.goals import GoalPipeline
from hsa_dynamixel_driver.neutral import configured_neutral, write_neutral_file

# wall-clock wait for rebooted servos to answer a ping again (bus-level, like the SDK timeouts)
REBOOT_WAIT_S = 2.0
COUNTERS = (
    "cycles",
    "writes",
    "reads",
    "commands",
    "rejected",
    "clamped",
    "ignored",
    "reconnect_attempts",
    "reconnects",
    "bus_losses",
    "port_errors",
    "comm_errors",
    "status_errors",
    "estops",
    "rate_limited",
    "reboots",
)


@dataclasses.dataclass(frozen=True)
class GoalOut:
    """A goal written to the bus: as twists [rad], with its command's header stamp (None: no
    command) and source stamp."""

    phi: np.ndarray
    issued: Any
    source_stamp: Any


@dataclasses.dataclass(frozen=True)
class Exchange:
    """What one control cycle wrote and read (None: nothing)."""

    goal: GoalOut | None = None
    reading: PositionReading | None = None


class Servos:
    """The bus, the φ map and goal limits, the goal pipeline, the counters and the supervisor: the
    owner of the driver's state. The node calls one method per event and publishes what it returns;
    ``p`` are its parameters."""

    def __init__(self, p: dict[str, Any], logger: Any, now: Callable[[], float]) -> None:
        """Load the model and wiring, fix the configured neutral (a refused parameter raises
        ParameterValidationError)."""
        self._p, self._log, self._now = p, logger, now
        # motor IDs, rods and rod signs: the robot's wiring file
        self.wiring = load_wiring_param(p["wiring_file"])
        self._model = load_model(p)  # the rods' handedness and twist limit
        # the φ limit; the motor map's goal clamp is its `motor` bound
        self.limit = self._model.phi_limit
        self.ids: list[int] = list(self.wiring.motor_ids)
        self.stored_neutral = configured_neutral(p, self.ids, self.wiring.neutral_ticks)
        self.sup = ServoSupervisor(
            tuple(self.ids),
            p["error_limit"],
            p["neutral_tolerance"],
            describe_hardware_error,
            p["torque_retry_period"],
            p["torque_retry_max"],
        )
        self.goals = GoalPipeline()
        self.counts = dict.fromkeys(COUNTERS, 0)
        self._rejections = RejectionLog()
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
        self.sup.commands.clear()

    # ------------------------------------------------------------------ neutral ticks
    def _set_neutral(self, ticks: list[int]) -> None:
        """Build the motor map, the absolute goal clamp and the sane range around the configured
        neutral ticks; a read neutral may later replace the map's zero (``_refine_map``), never
        these limits."""
        self.map = self.wiring.motor_map(
            self._model, neutral_ticks=tuple(ticks), margin=self._p["goal_margin"]
        )
        self.limits = MotorLimits.from_map(self.map)
        self.sup.positions.calibrate(self.map)

    def _refine_map(self) -> None:
        """neutral_source 'read': the present positions become the φ map's zero if they lie within
        neutral_tolerance of the configured neutral ticks; the goal limits stay where the
        configuration put them."""
        neutral = self.sup.positions.neutral
        assert self.bus is not None and self.map is not None and neutral is not None
        ticks = self.present_ticks(self.bus.read_positions().ticks).tolist()
        problem = accept_read_neutral(ticks, neutral, self._p["neutral_tolerance"])
        if problem is not None:
            self._log.warning(f"{problem}: the φ map keeps the configured neutral ticks")
            return
        self.map = dataclasses.replace(self.map, neutral_ticks=tuple(ticks))
        self._log.info(f"φ map zero read from the servos: {ticks} (limits on {neutral.tolist()})")

    def _adopt_present_as_neutral(self) -> None:
        """First start with a missing neutral file: the present positions become the stored
        calibration, unless the supervisor refuses them (servos held at start): then nothing is
        stored and torque stays off."""
        assert self.bus is not None
        ticks = self.present_ticks(self.bus.read_positions().ticks).tolist()
        self._set_neutral(ticks)  # also gives the state topics their zero while uncalibrated
        path = self._p["neutral_file"]
        problem = self.sup.positions.first_calibration(path)
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
        self.bus = DynamixelBus(
            self._p["port"],
            self._p["baudrate"],
            self.ids,
            min_packet_timeout_ms=self._p["packet_timeout"],
        )
        self.map = self.limits = None
        self.sup.configured(self.stored_neutral is not None)
        if self.stored_neutral is not None:
            self._set_neutral(self.stored_neutral)

    def connect(self) -> None:
        """Open the bus, configure the servos (torque off, return delay, extended position mode),
        fix neutrals; then torque on if it is due."""
        assert self.bus is not None
        try:
            self.bus.close()
            self.bus.open()
            positions = self.sup.positions
            if positions.needs_held_check():  # before configure() turns torque off: still held?
                positions.held = all(
                    self.bus.read_register(i, ADDR_TORQUE_ENABLE, 1) == 1 for i in self.ids
                )
            self.bus.configure(return_delay=self._p["return_delay"])
            if self.map is None:
                self._adopt_present_as_neutral()
            elif self._p["neutral_source"] == "read" and not self.sup.positions.startup_checked:
                self._refine_map()
        except BusError as exc:
            self.count_error(exc)
            self.bus.close()
            if self.sup.link.connect_failed(str(exc)):
                self._log.warning(
                    f"bus not ready ({exc}); retrying every {self._p['reconnect_period']} s"
                )
            return
        outage = self.sup.link.connected(self._now())
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
        if not self.sup.link.up:
            self.counts["reconnect_attempts"] += 1
            self.connect()

    def lose_link(self, exc: BusError) -> None:
        """The bus stopped answering: torque off where still possible, close, let the reconnect
        timer retry."""
        assert self.bus is not None
        self._log.error(
            f"bus lost ({exc}); torque off, reconnecting every {self._p['reconnect_period']} s"
        )
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
        kind = (
            "port_errors"
            if isinstance(exc, PortError)
            else "comm_errors"
            if isinstance(exc, CommError)
            else "status_errors"
            if isinstance(exc, ServoStatusError)
            else "comm_errors"
        )
        self.counts[kind] += 1

    # ------------------------------------------------------------------ torque
    def _checked(self, check: Callable[[], str | None]) -> str | None:
        """Run one of the supervisor's torque-on checks; warn once when it keeps the pose of servos
        held at start."""
        positions = self.sup.positions
        checked = positions.startup_checked
        problem = check()
        if not checked and positions.startup_checked and positions.held:
            self._log.warning(
                "servos still held at start (driver restart): keeping their pose within the limits "
                f"of the configured neutral ticks {positions.neutral.tolist()}"
            )
        return problem

    def enable_torque(self) -> str | None:
        """Torque on holding the present positions if the supervisor allows it; returns why not
        otherwise. A refusal by the checks stays until asked again; a failure on the bus is retried
        with backoff while torque is due."""
        assert self.bus is not None
        try:
            reading = self.bus.read_positions()
            errors = self._hardware_errors() if reading.alerts else None
            ticks = self.present_ticks(reading.ticks)
            problem = self._checked(
                lambda: self.sup.torque_on_problem(ticks, reading.alerts, errors)
            )
            if problem is None:
                self.bus.enable_torque()
        except BusError as exc:
            self.count_error(exc)
            # servos enabled before the failure must not stay on
            self.bus.disable_torque(verify=False)
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
        """Best-effort torque off (one sync write, then read back); returns and logs the IDs that
        did not confirm."""
        was_on = self.sup.torque_disabled(reason)
        if self.bus is None or not self.bus.is_open:
            return frozenset(self.ids)
        unconfirmed = self.bus.disable_torque()
        # once more after a pause, so a half-finished exchange (e.g. cut by a signal) has died out
        if unconfirmed:
            time.sleep(0.1)
            unconfirmed = self.bus.disable_torque()
        if unconfirmed:
            self._log.error(f"torque off ({reason}) not confirmed by IDs {sorted(unconfirmed)}")
        elif was_on:
            self._log.info(f"torque off ({reason})")
        return unconfirmed

    def _hardware_errors(self) -> dict[int, int]:
        """Hardware Error Status of the servos that report one (nonzero bits only), read from the
        bus."""
        assert self.bus is not None
        return {i: b for i, b in self.bus.read_hardware_errors().items() if b}

    def alerts(self, alerts: frozenset[int]) -> None:
        """The set of alerting servos changed: read their Hardware Error Status; on a new error,
        torque off for all."""
        assert self.bus is not None
        errors = self._hardware_errors() if alerts else {}
        event = self.sup.hardware_errors(alerts, errors)
        if event is Alert.FAULT:
            self.disable_torque("hardware error")
            problem = self.sup.hardware.problem() or ""
            self.sup.torque_refused(problem)
            self._log.error(f"torque off: {problem}")
        elif event is Alert.CLEARED:
            self._log.info("hardware errors cleared")

    def reboot(self, ids: list[int]) -> Answer:
        """Protocol 2.0 REBOOT of ``ids`` (torque off for every servo first), then configure,
        re-read the hardware errors and present positions and re-check them; torque stays off until
        ``set_torque(true)``."""
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
            # RAM defaults: torque off; EEPROM checked
            self.bus.configure(return_delay=self._p["return_delay"])
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
        self.last_reboot = f"IDs {ids} in {took * 1e3:.1f} ms: " + (
            problem or "ready for set_torque(true)"
        )
        self.sup.torque_refused(f"off (rebooted IDs {ids}{': ' + problem if problem else ''})")
        if problem is not None:
            self._log.error(f"rebooted IDs {ids}; torque stays off: {problem}")
        else:
            self._log.warning(
                f"rebooted IDs {ids} in {took * 1e3:.1f} ms: hardware errors cleared, present "
                "positions within the limits; torque off until set_torque(true)"
            )
        return Answer(
            problem is None,
            f"rebooted IDs {ids}; "
            + (
                f"torque stays off: {problem}"
                if problem
                else "hardware errors cleared, positions within the limits: call set_torque(true)"
            ),
        )

    # ------------------------------------------------------------------ node events
    def activate(self) -> None:
        """The node activates: discard the command, torque on if it is due."""
        self.goals.clear()
        if self.sup.activate():
            self.enable_torque()

    def deactivate(self) -> None:
        """The node deactivates (the caller switches torque off where needed)."""
        self.sup.deactivate()

    def lockstep_ready(self) -> bool:
        """Connected, active and torque on if wanted."""
        sup = self.sup
        return sup.active and sup.link.up and (sup.torque_on or not sup.torque_wanted)

    def take_command(self, phi_cmd: Any) -> GoalOut | None:
        """A phi_cmd (PlanarActuation) arrived: keep the newest finite one (ignored while the E-stop
        is engaged); with ``write_on_command`` its goal leaves now and is returned."""
        verdict = self.sup.command(bool(np.all(np.isfinite(phi_cmd.phi))))
        if verdict is Verdict.REJECT:
            self.counts["rejected"] += 1
            self._log_rejection("rejected", f"non-finite phi {list(phi_cmd.phi)}")
            return None
        if verdict is Verdict.IGNORE:
            self.counts["ignored"] += 1
            return None
        self.counts["commands"] += 1
        if verdict is Verdict.WAKE and self.enable_torque() is None:
            self._log.info("phi_cmd resumed: torque on again after the watchdog relaxed the motors")
        self.goals.take(phi_cmd)
        self.sup.commands.taken(self._now())
        if not (self._p["write_on_command"] and self.sup.active and self.sup.link.up):
            return None
        try:  # the goal leaves now instead of waiting up to one read period (compute-path latency)
            return self._write_goal()
        except BusError as exc:
            self.count_error(exc)  # the next cycle retries the write and handles a lost link
            return None

    def _log_rejection(self, kind: str, detail: str) -> None:
        """WARN about a rejected or clipped command, throttled by RejectionLog (the counters count
        every one)."""
        line = self._rejections.record(kind, detail, self._now())
        if line is not None:
            self._log.warning(line)

    def set_torque(self, on: bool) -> Answer:
        """set_torque: off at once (and unwanted), or on if active, connected, unstopped, sane."""
        if not on:
            self.sup.torque_unwanted()
            self.disable_torque("set_torque service")
            return Answer(True, "torque off")
        refusal = self.sup.set_torque_refusal()
        return refusal or self.sup.set_torque_result(self.enable_torque())

    def engage_estop(self, reason: str) -> tuple[bool, str]:
        """Torque off at once, stop writing goals and ignore phi_cmd until clear_estop; returns
        whether this engaged the E-stop (it was released: publish) and the torque-off outcome."""
        unconfirmed = self.disable_torque("E-stop")
        self.clear_command()
        outcome = self.sup.torque_off_outcome(unconfirmed)
        engaged = self.sup.estop.engage(reason, self._now())
        if engaged:
            self.counts["estops"] += 1
            self._log.error(
                f"E-stop engaged ({reason}): {outcome}; phi_cmd ignored until clear_estop"
            )
        return engaged, outcome

    def clear_estop(self) -> tuple[Answer, bool]:
        """clear_estop: release only if torque can be re-enabled safely (same checks as a
        reconnect); returns the answer and whether the E-stop was released (publish)."""
        answer = self.sup.clear_estop_refusal()
        if answer is not None:
            return answer, False
        answer = self.sup.clear_estop_result(self.enable_torque())
        if answer.success:
            self._log.warning("E-stop cleared: torque on, holding the present positions")
        return answer, answer.success

    # ------------------------------------------------------------------ control cycle
    def exchange(self) -> Exchange:
        """One control cycle: watchdog, a due torque-on retry, at most one sync write of the newest
        command, one sync read, the hardware errors if the alerts changed; a failure counts towards
        losing the bus."""
        now = self._now()
        self.counts["cycles"] += 1
        if not self.sup.link.up:
            return Exchange()
        self._check_watchdog(now)
        if self.sup.torque_retry_due(now):
            self.enable_torque()
        assert self.bus is not None
        goal = reading = None
        try:
            goal = self._write_goal()
            reading = self.bus.read_positions()
            self.counts["reads"] += 1
            if self.sup.hardware.changed(reading.alerts):
                self.alerts(reading.alerts)
        except BusError as exc:
            self.count_error(exc)
            if self.sup.link.cycle_failed(isinstance(exc, PortError)):
                self.lose_link(exc)
            return Exchange(goal, reading)
        self.sup.link.cycle_succeeded()
        return Exchange(goal, reading)

    def _check_watchdog(self, now: float) -> None:
        """Command watchdog: act on the supervisor's decision (log once on expiry, relax, drop a
        stale target)."""
        timeout = self._p["command_timeout"]
        decision = self.sup.check_watchdog(now, timeout, self._p["watchdog_action"])
        if decision.event in (WatchdogEvent.HOLD, WatchdogEvent.RELAX):
            relax = decision.event is WatchdogEvent.RELAX
            taken = self.sup.commands.command_time
            age = now - (now if taken is None else taken)
            self._log.warning(
                f"no phi_cmd for {age:.3f} s (> {timeout} s): "
                + ("relaxing (torque off)" if relax else "holding the last goal")
            )
        if decision.torque_off:
            self.disable_torque("watchdog: no phi_cmd")
        if decision.stale:
            self.goals.drop_target()
        elif decision.event is WatchdogEvent.RESUMED:
            self._log.info("phi_cmd resumed")

    def _write_goal(self) -> GoalOut | None:
        """Sync-write the clamped (and rate-limited) goal of the newest command, if there is
        something to write."""
        if not self.sup.torque_on:
            self.goals.pending = False
            return None
        now = self._now()
        assert self.map is not None and self.limits is not None and self.bus is not None
        period = 1.0 / self._p["rate"]
        step = self.goals.next_goal(now, self.map, self.limits, self._p["max_goal_rate"], period)
        if step is None:
            return None
        if step.clipped is not None:
            self.counts["clamped"] += 1
            self._log_rejection("clipped", step.clipped)
        self.counts["rate_limited"] += step.rate_limited
        self.bus.write_goals({i: int(t) for i, t in zip(self.ids, step.ticks)})
        self.goals.written(step.ticks, now)
        self.counts["writes"] += 1
        command = self.goals.command
        issued = command.header.stamp if command is not None else None
        return GoalOut(self.map.present_twists(step.ticks), issued, self.goals.target_source)

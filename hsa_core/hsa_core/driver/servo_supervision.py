"""Servo supervision of the dynamixel_driver as a pure state machine: events in,
decisions out.

The driver does the I/O (bus, timers, services, logging) and reports what happened, with the
node-clock time in seconds passed in explicitly. `ServoSupervisor` keeps whether torque is wanted
and on and answers what to do; it is composed of one part per idea: `BusLink` (loss and reconnect),
`TorqueRetry` (backoff), `CommandWatchdog`, `EStopLatch`, `HardwareErrors` and `PositionCheck`
(calibration and start-up positions). The rules:

* torque is *wanted* from activation until ``set_torque(false)``, a hardware error, a reboot or
  deactivation; it may come on only while active, connected, not E-stopped, free of hardware errors
  and at sane present positions;
* command watchdog: no ``phi_cmd`` for more than ``command_timeout`` -> hold the last goal, or relax
  (torque off, ``relaxed``) until the next command, which switches torque on again if safe; it arms
  with the first command;
* E-stop: latched with its reason until ``clear_estop``, which needs an active node, a connected bus
  and a successful torque-on; commands are ignored and ``set_torque(true)`` refused meanwhile;
* link: a port error or ``error_limit`` consecutive failed cycles lose the bus; a reconnect reports
  the outage and re-enables torque only if it is wanted, not relaxed and not E-stopped;
* torque-on retry: a torque-on that torque is due for and that failed on the bus (`torque_failed`,
  not a refusal by the checks) is tried again after a delay that starts at ``retry_period`` and
  doubles with each failure in a row up to ``retry_max`` (`torque_retry_due`); a refusal, a success,
  a lost link or torque no longer due ends the retries;
* `takes_commands`: whether a phi_cmd moves the servos now (torque on) or switches torque on when it
  arrives (relaxed by the watchdog); the driver publishes it for the controller, which leaves
  tracking while it is false;
* start-up positions: the first torque-on after configure with a configured neutral needs every
  motor within ``neutral_tolerance`` of it unless the servos were still held (``neutral_check``);
  every torque-on needs the present positions inside the goal limits widened by
  ``neutral_tolerance``; a first calibration is refused on held servos;
* reboot: refused while tracking fresh commands with torque on (`reboot_refusal`); afterwards the
  hardware errors and positions are checked again and torque stays off until asked for.

The goal speed limit on the same clock is :class:`hsa_core.model.actuation.GoalRateLimiter`.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from hsa_core.model.actuation import MotorLimits, MotorMap, neutral_check, ticks_to_angles

MULTI_TURN_NOTE = "a reboot resets the multi-turn count (present position within one turn)"


class Watchdog(str, enum.Enum):
    """State of the command watchdog; values are the names shown on /diagnostics."""

    WAITING = "waiting for the first command"
    FRESH = "fresh"
    EXPIRED = "expired"


class WatchdogEvent(enum.Enum):
    """What one control cycle's watchdog check found."""

    NONE = "none"  # no command yet, or still fresh
    STALE = "stale"  # still expired: write nothing
    HOLD = "hold"  # just expired, action 'hold': keep the last goal
    RELAX = "relax"  # just expired, action 'relax'
    RESUMED = "resumed"  # fresh again after an expiry


@dataclasses.dataclass(frozen=True)
class WatchdogDecision:
    """The watchdog event of a cycle; torque_off: switch torque off now (relax with torque on)."""

    event: WatchdogEvent
    torque_off: bool = False

    @property
    def stale(self) -> bool:
        """No fresh command: drop the target, write nothing."""
        return self.event in (WatchdogEvent.STALE, WatchdogEvent.HOLD, WatchdogEvent.RELAX)


class Verdict(enum.Enum):
    """What to do with an arriving phi_cmd."""

    REJECT = "reject"  # non-finite
    IGNORE = "ignore"  # E-stop engaged
    ACCEPT = "accept"
    WAKE = "wake"  # accept after switching torque on again (relaxed by the watchdog)


class Alert(enum.Enum):
    """Outcome of a changed set of hardware errors."""

    NONE = "none"
    FAULT = "fault"  # a new error: torque off for every servo
    CLEARED = "cleared"


@dataclasses.dataclass(frozen=True)
class Answer:
    """A service answer: success and message."""

    success: bool
    message: str


@dataclasses.dataclass
class BusLink:
    """Whether the bus answers: failed cycles in a row, the problem while it is down, the last
    outage [s]."""

    error_limit: int  # consecutive failed cycles that lose the bus
    up: bool = False
    consecutive_failures: int = 0
    problem: str = ""
    lost_at: float | None = None
    last_outage_s: float | None = None

    def connect_failed(self, problem: str) -> bool:
        """Opening the bus failed; True when the problem is new (log it once)."""
        new = problem != self.problem
        self.problem = problem
        return new

    def connected(self, now: float) -> float | None:
        """The bus is open and configured; returns the outage [s] ending a loss, else None."""
        self.up, self.problem, self.consecutive_failures = True, "", 0
        if self.lost_at is None:
            return None
        self.last_outage_s, self.lost_at = now - self.lost_at, None
        return self.last_outage_s

    def cycle_failed(self, port_error: bool) -> bool:
        """A cycle's bus exchange failed; True when the bus counts as lost (port error or
        error_limit in a row)."""
        self.consecutive_failures += 1
        return port_error or self.consecutive_failures >= self.error_limit

    def cycle_succeeded(self) -> None:
        """A cycle's write and read succeeded."""
        self.consecutive_failures = 0

    def lost(self, problem: str, now: float) -> None:
        """The bus was lost at ``now`` [s]: down until a reconnect."""
        self.up, self.problem, self.lost_at = False, problem, now


@dataclasses.dataclass
class TorqueRetry:
    """Backoff of a torque-on that failed on the bus: ``period`` [s] doubled per failure in a row,
    at most ``longest`` [s]."""

    period: float = 0.25  # first delay [s]
    longest: float = 5.0  # largest delay [s] (at least period)
    failures: int = 0  # torque-on attempts failed on the bus in a row
    at: float | None = None  # when the torque-on is tried again, None: no retry pending

    def schedule(self, now: float) -> float:
        """One more failure at ``now`` [s]: the delay [s] until the next try."""
        doublings = min(self.failures, 64)  # beyond any longest/period ratio; no float overflow
        delay = min(self.period * 2.0**doublings, max(self.longest, self.period))
        self.failures += 1
        self.at = now + delay
        return delay

    def end(self) -> int:
        """No retry pending; the next failure starts from ``period`` again. Returns the failures in
        a row."""
        failures, self.failures, self.at = self.failures, 0, None
        return failures


@dataclasses.dataclass
class CommandWatchdog:
    """Age of the newest phi_cmd [s]: armed by the first command, expired after the timeout."""

    state: Watchdog = Watchdog.WAITING
    command_time: float | None = None

    def taken(self, now: float) -> None:
        """The newest command arrived at ``now`` [s]."""
        self.command_time = now

    def clear(self) -> None:
        """The command was discarded: wait for a new one."""
        self.command_time, self.state = None, Watchdog.WAITING

    def check(self, now: float, timeout: float, action: str) -> WatchdogEvent:
        """One cycle's check: command older than ``timeout`` [s] (0 = off) -> ``action`` hold |
        relax, once."""
        if self.command_time is None:
            return WatchdogEvent.NONE
        if timeout > 0.0 and now - self.command_time > timeout:
            if self.state is Watchdog.EXPIRED:
                return WatchdogEvent.STALE
            self.state = Watchdog.EXPIRED
            return WatchdogEvent.RELAX if action == "relax" else WatchdogEvent.HOLD
        resumed, self.state = self.state is Watchdog.EXPIRED, Watchdog.FRESH
        return WatchdogEvent.RESUMED if resumed else WatchdogEvent.NONE


@dataclasses.dataclass
class EStopLatch:
    """The E-stop: engaged with its first reason and time [s] until released."""

    reason: str | None = None  # None while released
    since: float = 0.0

    def engage(self, reason: str, now: float) -> bool:
        """Latch; True when it was released before (publish, log)."""
        if self.reason is not None:
            return False
        self.reason, self.since = reason, now
        return True


@dataclasses.dataclass
class HardwareErrors:
    """The servos' Hardware Error Status bits and which servos raise the alert flag."""

    describe: Callable[[int], str]  # Hardware Error Status bits -> text
    errors: dict[int, int] = dataclasses.field(default_factory=dict)
    alerts: frozenset[int] = frozenset()

    def changed(self, alerts: frozenset[int]) -> bool:
        """Whether a read's set of alerting servos differs from the known one (read Hardware Error
        Status then)."""
        return alerts != self.alerts

    def update(self, alerts: frozenset[int], errors: dict[int, int]) -> Alert:
        """The alerting servos with these nonzero errors: new errors, cleared, or nothing new."""
        self.alerts = alerts
        if errors == self.errors:
            return Alert.NONE
        self.errors = errors
        return Alert.FAULT if errors else Alert.CLEARED

    def problem(self) -> str | None:
        """The errors as a torque-on refusal, or None."""
        if not self.errors:
            return None
        described = {i: self.describe(b) for i, b in self.errors.items()}
        return f"hardware error {described}: call reboot (or reboot_<id>), or power-cycle the servo"


@dataclasses.dataclass
class PositionCheck:
    """Start-up positions: the calibration, the start-up check against the configured neutral and
    the sane range."""

    ids: tuple[int, ...]
    tolerance: float  # neutral_tolerance [rad]
    neutral: np.ndarray | None = None  # configured neutral ticks: the limits' reference
    sane: MotorLimits | None = None  # goal limits widened by the tolerance: torque may come on here
    held: bool = False  # every servo still had torque on at the first connection (a driver restart)
    startup_checked: bool = False
    uncalibrated: str | None = None  # why no neutral is trustworthy (torque stays off), or None

    def configured(self, neutral_known: bool) -> None:
        """Configure: a configured neutral is checked at the first torque-on; without one the
        present positions become the calibration (nothing to check)."""
        self.neutral = self.sane = None
        self.startup_checked, self.held, self.uncalibrated = not neutral_known, False, None

    def needs_held_check(self) -> bool:
        """Whether a connection must read Torque Enable (before configure switches it off): until
        the start-up check passed, or before a first calibration."""
        return self.neutral is None or not self.startup_checked

    def calibrate(self, motor_map: MotorMap) -> None:
        """The configured neutral of ``motor_map`` fixes the sane range: its goal limits widened by
        the tolerance."""
        self.neutral = np.asarray(motor_map.neutral_ticks, dtype=np.int64)
        wider = dataclasses.replace(motor_map, margin=motor_map.margin + self.tolerance)
        self.sane = MotorLimits.from_map(wider)

    def first_calibration(self, path: str) -> str | None:
        """No neutral file yet: why the present positions must not be stored as the calibration
        (servos held at start, a commanded pose rather than the rest pose: torque then stays off),
        or None."""
        if self.held:
            self.uncalibrated = (
                f"no neutral file {path} and the servos were held at start "
                "(not necessarily at rest): switch their torque off or "
                "power-cycle them at rest, then restart"
            )
        return self.uncalibrated

    def problem(self, ticks: np.ndarray) -> str | None:
        """Why torque must not come on at these present ticks: uncalibrated, start-up check, sane
        range."""
        assert self.neutral is not None and self.sane is not None
        if self.uncalibrated is not None:
            return self.uncalibrated
        if not self.startup_checked:
            problem = neutral_check(ticks_to_angles(ticks, self.neutral), self.tolerance, self.held)
            if problem is not None:
                return problem
            self.startup_checked = True
        inside = self.sane.contains(ticks)
        if not np.all(inside):
            outside = [i for i, ok in zip(self.ids, inside) if not ok]
            return (
                f"present positions of IDs {outside} are outside the goal limits (servo "
                "power-cycled or turned?)"
            )
        return None


class ServoSupervisor:
    """Whether torque is wanted and on, composed with the link, retry, watchdog, E-stop,
    hardware-error and position parts; it answers the decisions that span them. Times are node-clock
    seconds."""

    def __init__(
        self,
        ids: tuple[int, ...],
        error_limit: int,
        tolerance: float,
        describe_error: Callable[[int], str],
        retry_period: float = 0.25,
        retry_max: float = 5.0,
    ) -> None:
        """``error_limit`` failed cycles in a row lose the bus; ``tolerance`` [rad] is
        neutral_tolerance."""
        self.link = BusLink(error_limit)
        self.retry = TorqueRetry(retry_period, retry_max)
        self.commands = CommandWatchdog()
        self.estop = EStopLatch()
        self.hardware = HardwareErrors(describe_error)
        self.positions = PositionCheck(ids, tolerance)
        self.active = False
        self.torque_on = False
        self.torque_wanted = False
        self.relaxed = False  # torque off by the watchdog's relax until the next phi_cmd
        self.note = "not configured"  # torque state and why, for diagnostics

    # ---------------------------------------------------------------- lifecycle and link
    def configured(self, neutral_known: bool) -> None:
        """Configure (see `PositionCheck.configured`)."""
        self.positions.configured(neutral_known)
        self.note = "inactive"

    def activate(self) -> bool:
        """Activate: torque wanted, the command discarded; True when torque should be switched on
        now."""
        self.active, self.torque_wanted, self.relaxed = True, True, False
        self.commands.clear()
        return self.torque_due()

    def deactivate(self) -> None:
        """Deactivate (also cleanup, shutdown, error): torque no longer wanted."""
        self.active = self.torque_wanted = self.relaxed = False
        self.retry.end()

    def released(self) -> None:
        """The bus was closed and the node deactivated."""
        self.link.up = False
        self.deactivate()

    def torque_due(self) -> bool:
        """Torque should be on and may be tried: active, connected, wanted, not relaxed, no
        E-stop."""
        return (
            self.active
            and self.link.up
            and self.torque_wanted
            and not self.relaxed
            and self.estop.reason is None
        )

    def link_lost(self, problem: str, now: float) -> None:
        """The bus was lost (torque already switched off where possible): reconnect until it
        answers."""
        self.link.lost(problem, now)
        self.retry.end()  # the reconnect tries torque on itself

    # ---------------------------------------------------------------- torque
    def torque_enabled(self) -> int:
        """Torque came on holding the present positions; returns the failed attempts before it
        (retries end)."""
        self.torque_on, self.relaxed, self.note = True, False, "on"
        return self.retry.end()

    def torque_disabled(self, reason: str) -> bool:
        """Torque was switched off for ``reason``; True when it had been on."""
        was_on, self.torque_on, self.note = self.torque_on, False, f"off ({reason})"
        return was_on

    def torque_refused(self, problem: str) -> bool:
        """Torque stays off for ``problem`` (a refusal: no retry); True when the reason changed (log
        it once)."""
        changed, self.note = problem != self.note, problem
        self.retry.end()
        return changed

    def torque_failed(self, problem: str, now: float) -> float | None:
        """A torque-on failed on the bus at ``now`` [s]: while torque is due, retry after the
        returned delay [s] (see `TorqueRetry`); None: not due, no retry."""
        self.note = problem
        if not self.torque_due():
            self.retry.end()
            return None
        return self.retry.schedule(now)

    def torque_retry_due(self, now: float) -> bool:
        """Whether the failed torque-on is to be tried again now (its delay is over and torque is
        still due)."""
        if self.retry.at is None or self.torque_on:
            return False
        if not self.torque_due():
            self.retry.end()
            return False
        return now >= self.retry.at

    def takes_commands(self) -> bool:
        """Whether a phi_cmd moves the servos: torque on, or off only by the watchdog's relax (a
        command switches it on again)."""
        return self.torque_on or (
            self.relaxed
            and self.torque_wanted
            and self.active
            and self.link.up
            and self.estop.reason is None
        )

    def torque_unwanted(self) -> None:
        """Torque off on request (set_torque(false)): it stays off, also across reconnects, until
        asked again."""
        self.torque_wanted = False
        self.retry.end()

    def set_torque_refusal(self) -> Answer | None:
        """set_torque(true): the answer without trying (refused, or already on), or None: try torque
        on now."""
        if self.estop.reason is not None:
            return Answer(False, f"E-stop engaged ({self.estop.reason}): call clear_estop")
        if not self.active:
            return Answer(False, "node is not active")
        if self.torque_on:
            return Answer(True, "torque already on")
        if not self.link.up:
            return Answer(False, f"bus not connected: {self.link.problem}")
        return None

    def set_torque_result(self, problem: str | None) -> Answer:
        """set_torque(true) tried torque on: wanted only if it came on; a relax ends either way."""
        self.torque_wanted, self.relaxed = problem is None, False
        return Answer(problem is None, problem or "torque on")

    def torque_on_problem(
        self, ticks: ArrayLike, alerts: frozenset[int], errors: dict[int, int] | None
    ) -> str | None:
        """Why torque must not come on at these present ticks (in ``ids`` order), or None;
        ``errors`` are the Hardware Error Status bits read with the positions (None: not read,
        nothing was alerting)."""
        if errors is not None:
            self.hardware.errors = errors
        self.hardware.alerts = alerts
        return self.hardware.problem() or self.positions.problem(np.asarray(ticks, dtype=np.int64))

    def hardware_errors(self, alerts: frozenset[int], errors: dict[int, int]) -> Alert:
        """The set of alerting servos changed, with these nonzero errors: a new error stops wanting
        torque."""
        alert = self.hardware.update(alerts, errors)
        if alert is Alert.FAULT:
            self.torque_wanted = False
        return alert

    # ---------------------------------------------------------------- commands and watchdog
    def command(self, finite: bool) -> Verdict:
        """How to treat an arriving phi_cmd; after an ACCEPT (or a WAKE, whatever its torque-on
        gave) the caller reports it to ``commands.taken``."""
        if not finite:
            return Verdict.REJECT
        if self.estop.reason is not None:
            return Verdict.IGNORE
        if self.relaxed and self.torque_wanted and self.active and self.link.up:
            return Verdict.WAKE
        return Verdict.ACCEPT

    def check_watchdog(self, now: float, timeout: float, action: str) -> WatchdogDecision:
        """Watchdog check of one cycle (see `CommandWatchdog.check`); a relax with torque on
        switches it off."""
        event = self.commands.check(now, timeout, action)
        if event is not WatchdogEvent.RELAX:
            return WatchdogDecision(event)
        if self.torque_on:
            self.relaxed = True
        return WatchdogDecision(event, torque_off=self.torque_on)

    def watchdog_status(self, action: str) -> str:
        """Watchdog state for diagnostics: expired with 'relaxed' or the action, else the state's
        name."""
        state = self.commands.state
        if state is not Watchdog.EXPIRED:
            return state.value
        return f"{state.value} ({'relaxed' if self.relaxed else action})"

    # ---------------------------------------------------------------- E-stop
    def torque_off_outcome(self, unconfirmed: frozenset[int]) -> str:
        """What a torque-off achieved, given the IDs that did not confirm it."""
        if not unconfirmed:
            return "torque off confirmed"
        if self.link.up:
            return f"torque off not confirmed by IDs {sorted(unconfirmed)}"
        return f"bus not connected ({self.link.problem}): torque off not possible"

    def clear_estop_refusal(self) -> Answer | None:
        """clear_estop: the answer without trying (nothing engaged, inactive, disconnected), or
        None: try torque on."""
        if self.estop.reason is None:
            return Answer(True, "E-stop was not engaged")
        if not self.active:
            return Answer(False, "E-stop stays engaged: node is not active")
        if not self.link.up:
            return Answer(False, f"E-stop stays engaged: bus not connected: {self.link.problem}")
        return None

    def clear_estop_result(self, problem: str | None) -> Answer:
        """clear_estop tried torque on: released (torque wanted again) only if it came on."""
        if problem is not None:
            return Answer(False, f"E-stop stays engaged: {problem}")
        self.estop.reason, self.torque_wanted, self.relaxed = None, True, False
        return Answer(True, "E-stop cleared, torque on")

    # ---------------------------------------------------------------- reboot
    def reboot_refusal(self) -> str | None:
        """Why a reboot must be refused now (see `reboot_refusal`), or None."""
        tracking = self.commands.state is Watchdog.FRESH
        return reboot_refusal(self.active, self.link.up, self.torque_on, tracking)

    def reboot_started(self) -> None:
        """A reboot begins (torque is switched off for every servo): torque stays off until
        set_torque(true)."""
        self.torque_wanted = self.relaxed = False

    def rebooted(
        self, ticks: ArrayLike, alerts: frozenset[int], errors: dict[int, int]
    ) -> str | None:
        """The servos answered after a reboot with these positions and nonzero errors: why torque
        must stay off (a position problem without hardware errors names the lost multi-turn count),
        or None."""
        problem = self.torque_on_problem(ticks, alerts, errors)
        if problem is not None and not errors:
            problem = f"{problem}; {MULTI_TURN_NOTE}"
        return problem


def reboot_refusal(active: bool, link_up: bool, torque_on: bool, tracking: bool) -> str | None:
    """Why a servo reboot must be refused now, or None.

    A reboot drops the servo's torque at once (the instruction resets its RAM), so it is refused
    while the robot is tracking fresh commands with torque on; holding or idle servos may be
    rebooted (the driver switches every servo's torque off first, so a rod pair is never left half
    held).
    """
    if not active:
        return "node is not active"
    if not link_up:
        return "bus not connected"
    if torque_on and tracking:
        return (
            "torque is on and the robot is tracking fresh phi_cmd: stop the commands (or call "
            "set_torque(false)) before a reboot"
        )
    return None

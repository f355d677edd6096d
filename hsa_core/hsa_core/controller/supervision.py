"""Controller supervision (planning_and_control.md §5) as a pure state machine: events in,
decision out.

The node (or any loop) reports events with the time passed in explicitly (int nanoseconds on one
clock, the one the state stamps use): a setpoint accepted, a state received (with its stamp), a
driver heartbeat, the driver's torque state, the E-stop state. Each control tick asks `tick(now)`
for the decision, in this priority:

1. E-stop active -> ESTOP, send nothing (the integrators are reset when the E-stop is entered);
2. no setpoint yet -> WAITING_FOR_SETPOINT;
3. driver watched (driver_timeout > 0): no heartbeat yet -> WAITING_FOR_DRIVER; none for
   driver_timeout -> DRIVER_LOST; send nothing, integrators frozen, until heartbeats return; the
   driver reports its servos' torque off (not merely relaxed by its watchdog) -> TORQUE_OFF; send
   nothing, integrators frozen, until it is on again (no report yet counts as on: a driver that
   never reports is judged by its heartbeats alone);
4. no usable state yet -> WAITING_FOR_STATE;
5. state age (tick time - its stamp; tick time - its arrival when stamps are not on this clock) <=
   stale_timeout -> TRACKING (step the law); <= hold_timeout and a command was sent before -> HOLD
   (re-send the last command, integrators frozen); else STALE (send nothing).

States are ordered by stamp: one not newer than the newest accepted one is refused, as is one
stamped more than stale_timeout in the future (it would otherwise hide every genuine state after
it). Only TRACKING steps the law, so the integrators are frozen in every other mode.
"""

from __future__ import annotations

import dataclasses
import enum

from hsa_core.refusal import Refusal, StateRejection

STALE_TIMEOUT, HOLD_TIMEOUT, DRIVER_TIMEOUT = 0.1, 0.25, 0.25
"""Default bounds [s] of controller_node's `stale_timeout`, `hold_timeout` and `driver_timeout`
(docs/nodes)."""


class Mode(str, enum.Enum):
    """Supervision mode; values are the names shown on /diagnostics."""

    WAITING_FOR_SETPOINT = "waiting for setpoint"
    WAITING_FOR_DRIVER = "waiting for driver"
    WAITING_FOR_STATE = "waiting for state"
    TRACKING = "tracking"
    HOLD = "holding (stale)"
    STALE = "stale (no command)"
    DRIVER_LOST = "driver lost"
    TORQUE_OFF = "driver torque off"
    ESTOP = "stopped (E-stop)"


class Action(enum.Enum):
    """What the tick does: step the law and send its command, re-send the last command, or send
    nothing."""

    STEP = "step"
    HOLD = "hold"
    NONE = "none"


@dataclasses.dataclass(frozen=True)
class Decision:
    """Mode and action of one tick; age_s [s] of the newest state (NaN without one), silence_s [s]
    of the driver."""

    mode: Mode
    action: Action
    age_s: float
    driver_silence_s: float


@dataclasses.dataclass(frozen=True)
class SupervisorConfig:
    """Bounds [s]: stale_timeout <= hold_timeout; driver_timeout 0 = no driver in this graph;
    stamp_clock False judges state age on arrival (only for recorded stamps that are not on this
    clock, e.g. a replay)."""

    stale_timeout: float
    hold_timeout: float
    driver_timeout: float
    stamp_clock: bool = True

    def __post_init__(self) -> None:
        """Refuse inconsistent bounds."""
        if not 0.0 < self.stale_timeout <= self.hold_timeout:
            raise ValueError(
                f"need 0 < stale_timeout <= hold_timeout, got {self.stale_timeout}, "
                f"{self.hold_timeout}"
            )
        if self.driver_timeout < 0.0:
            raise ValueError(
                f"driver_timeout must be >= 0 (0: no driver), got {self.driver_timeout}"
            )


def _ns(seconds: float) -> int:
    """Seconds to int nanoseconds."""
    return int(round(seconds * 1e9))


class Supervisor:
    """Mode state machine of the controller; every method takes the time as int nanoseconds."""

    def __init__(self, config: SupervisorConfig) -> None:
        """Start waiting for a setpoint, with no state, no heartbeat and no E-stop."""
        self.config = config
        self._stale, self._hold, self._driver = (
            _ns(v) for v in (config.stale_timeout, config.hold_timeout, config.driver_timeout)
        )
        self.has_setpoint = False
        self.estop = False
        self._stamp: int | None = None  # stamp of the newest accepted state
        self._arrival: int | None = None  # when it arrived
        self._heartbeat: int | None = None
        self.torque_off = False  # the driver reported its servos' torque off
        # a command was sent since start or the last E-stop (a hold needs one)
        self._commanded = False

    def setpoint_accepted(self) -> None:
        """A valid setpoint is active."""
        self.has_setpoint = True

    def state(self, stamp_ns: int, now_ns: int) -> Refusal | None:
        """A plausible state arrived: accept it as the newest, or return why it is refused
        (ordering, future)."""
        if self._stamp is not None and stamp_ns <= self._stamp:
            return Refusal.of(StateRejection.OLDER)
        if self.config.stamp_clock and stamp_ns - now_ns > self._stale:
            return Refusal.of(StateRejection.FUTURE)
        self._stamp, self._arrival = stamp_ns, now_ns
        return None

    def driver_heartbeat(self, now_ns: int) -> None:
        """The driver showed it is alive (a phi_present sample)."""
        self._heartbeat = now_ns

    def driver_torque(self, on: bool) -> bool:
        """The driver reported whether its servos take commands (torque on); True when that
        changed."""
        changed, self.torque_off = self.torque_off == on, not on
        return changed

    def set_estop(self, active: bool) -> bool:
        """E-stop state from the driver; True when it is entered (the caller then resets the
        integrators)."""
        entered = active and not self.estop
        self.estop = active
        if entered:
            self._commanded = False
        return entered

    def age_s(self, now_ns: int) -> float:
        """Age [s] of the newest state: by its stamp on the stamp clock, else by its arrival; NaN
        without one."""
        if self._stamp is None:
            return float("nan")
        return (now_ns - (self._stamp if self.config.stamp_clock else self._arrival)) * 1e-9

    def driver_silence_s(self, now_ns: int) -> float:
        """Time [s] since the last driver heartbeat (NaN without one)."""
        return float("nan") if self._heartbeat is None else (now_ns - self._heartbeat) * 1e-9

    def tick(self, now_ns: int) -> Decision:
        """The decision of one control tick at now_ns."""
        age, silence = self.age_s(now_ns), self.driver_silence_s(now_ns)
        mode, action = self._decide(now_ns)
        if action is not Action.NONE:
            self._commanded = True
        return Decision(mode, action, age, silence)

    def _decide(self, now_ns: int) -> tuple[Mode, Action]:
        """Mode and action by the priority of the module docstring."""
        if self.estop:
            return Mode.ESTOP, Action.NONE
        if not self.has_setpoint:
            return Mode.WAITING_FOR_SETPOINT, Action.NONE
        if self._driver > 0:
            if self._heartbeat is None:
                return Mode.WAITING_FOR_DRIVER, Action.NONE
            if now_ns - self._heartbeat > self._driver:
                return Mode.DRIVER_LOST, Action.NONE
            if self.torque_off:
                return Mode.TORQUE_OFF, Action.NONE
        if self._stamp is None:
            return Mode.WAITING_FOR_STATE, Action.NONE
        age_ns = now_ns - (self._stamp if self.config.stamp_clock else self._arrival)
        if age_ns <= self._stale:
            return Mode.TRACKING, Action.STEP
        if age_ns <= self._hold and self._commanded:
            return Mode.HOLD, Action.HOLD
        return Mode.STALE, Action.NONE

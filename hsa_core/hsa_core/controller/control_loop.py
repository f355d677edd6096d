"""One supervised controller tick as pure code (planning_and_control.md §5), shared by
controller_node (node clock) and the offline experiment (world clock), so that both take the same
decision on every tick.

Events come in with the time passed in as int nanoseconds on the clock of the state stamps:

* `receive_setpoint(stamp, setpoint, tag)` queues a setpoint; the first tick *after* its stamp
  activates it (a tick at the very instant it was stamped still uses the previous one, whichever
  arrived first: deterministic under simulated time). The newest wins, at a bounded cost per tick
  whatever the setpoint rate: the intake keeps the newest SETPOINT_INTAKE setpoints, and a tick
  checks its due setpoints from the newest back, at most SETPOINT_CHECKS of them, and activates the
  first that passes the optional physical check and `Controller.set_setpoint`; the newer ones it
  refused are counted as rejected, the older ones (and those the intake dropped) as superseded,
  unchecked. A refused setpoint leaves the previous one active;
* `state(stamp, now, ...)` checks plausibility (hsa_core.controller.validation.state_problem) and
  order (the Supervisor); an accepted state with valid velocities becomes the newest measurement;
* `heartbeat(now)` (driver alive), `driver_torque(on)` (whether the driver's servos take commands)
  and `set_estop(active)`: entering the E-stop resets the integrators and drops the held command, so
  it can never be re-sent after the stop.

`tick(now)` activates the due setpoints, asks the Supervisor (hsa_core.controller.supervision) and
then:

* STEP: `Controller.step` on the newest measurement; its command is sent and held from now on. A
  step the core refuses (ValueError) sends nothing and keeps the mode;
* HOLD with a held command: that command is re-sent unchanged (same φ, same source stamp); the law
  is not stepped, so the integrators are frozen;
* otherwise nothing is sent and the integrators are frozen (HOLD with nothing to hold is reported as
  STALE).

A mode change is returned once (`Transition`, with the time without tracking on a return to
tracking) and counted (entries into HOLD, STALE, DRIVER_LOST and TORQUE_OFF); `counters` and
`rejections` are cumulative.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hsa_core.controller.control import Controller, ControllerInfo, Measurement
from hsa_core.controller.supervision import Action, Decision, Mode, Supervisor
from hsa_core.controller.validation import SetpointRejection, q_bounds, state_problem
from hsa_core.rate_meter import RateMeter
from hsa_core.refusal import Refusal, StateRejection
from hsa_core.task.planning import Setpoint

DEADLINE_FACTOR = 1.5
"""A tick that starts more than 1.5 periods after the previous one counts as a deadline miss."""
SETPOINT_INTAKE = 16
"""Setpoints kept between two ticks; a newer arrival drops the oldest (superseded)."""
SETPOINT_CHECKS = 4
"""Due setpoints a tick checks at most, newest first; older due ones are superseded unchecked."""


@dataclasses.dataclass(frozen=True)
class Command:
    """A command sent: φ [rad] and the stamp [ns] of the state it was computed from (a hold re-sends
    both)."""

    phi: np.ndarray
    source_stamp_ns: int


@dataclasses.dataclass(frozen=True)
class Activation:
    """A queued setpoint a tick tried to activate: its tag (e.g. the message) and why it was refused
    (None: active)."""

    tag: Any
    problem: Refusal | None


@dataclasses.dataclass(frozen=True)
class Transition:
    """A mode change; outage_s [s] from the last tracking tick to this return to tracking (NaN
    otherwise)."""

    old: Mode
    new: Mode
    outage_s: float


@dataclasses.dataclass(frozen=True)
class Tick:
    """What one tick did; sent is STEP (a new command), HOLD (the held command re-sent) or NONE
    (nothing sent)."""

    decision: Decision
    mode: Mode  # the mode after the tick (unchanged when the core refused the step)
    sent: Action
    command: Command | None = None  # the command sent
    info: ControllerInfo | None = None  # the law's quantities (STEP)
    measurement: Measurement | None = None  # the state stepped on (STEP)
    compute_s: float = 0.0  # wall time of Controller.step [s]
    refused: str | None = None  # why the core refused the step
    transition: Transition | None = None
    activated: tuple[Activation, ...] = ()


@dataclasses.dataclass
class Counters:
    """Cumulative event counts (controller_node's /diagnostics values, in this order)."""

    ticks: int = 0
    deadline_misses: int = 0
    stale_events: int = 0  # entries into HOLD
    held_ticks: int = 0
    stale_stops: int = 0  # entries into STALE
    estop_events: int = 0
    driver_lost_events: int = 0
    torque_off_events: int = 0  # entries into TORQUE_OFF
    refused_ticks: int = 0
    saturated: int = 0
    received_setpoints: int = 0
    setpoints: int = 0  # activated
    rejected_setpoints: int = 0
    superseded_setpoints: int = 0  # replaced by a newer one before they were checked


@dataclasses.dataclass
class Rejections:
    """Refused inputs per reason and the text of the newest refusal of each kind ("-": none)."""

    states: Counter[StateRejection] = dataclasses.field(default_factory=Counter)
    setpoints: Counter[SetpointRejection] = dataclasses.field(default_factory=Counter)
    last_state: str = "-"
    last_setpoint: str = "-"


@dataclasses.dataclass(frozen=True)
class Period:
    """One reporting period: tick rate [Hz] and the compute time [s] of each step in it."""

    rate_hz: float
    compute_s: tuple[float, ...]


class ControlLoop:
    """The controller's supervised tick; every method takes the time as int nanoseconds (see the
    module docstring)."""

    def __init__(
        self,
        controller: Controller,
        supervisor: Supervisor,
        start_ns: int = 0,
        check: Callable[[Setpoint], Refusal | None] | None = None,
    ) -> None:
        """Wrap a compiled controller and a supervisor; `check` is the physical setpoint check
        before activation."""
        self.controller, self.supervisor, self._check = controller, supervisor, check
        self._q_bounds = q_bounds(controller.params)
        self.counters, self.rejections = Counters(), Rejections()
        self.mode = Mode.WAITING_FOR_SETPOINT
        # time without tracking before the latest return to tracking [s]
        self.last_outage_s = math.nan
        self.active_tag: Any = None  # tag of the active setpoint
        # received setpoints not yet checked, arrival order
        self._intake: deque[tuple[int, Setpoint, Any]] = deque()
        # stamp and values of the newest usable state
        self._newest: tuple[int, Measurement] | None = None
        self._held: Command | None = None
        self._last_tick: int | None = None
        self._tracked_at: int | None = None  # newest tracking tick
        # last tracking tick before the current outage (None while tracking)
        self._lost_at: int | None = None
        self._rate, self._window_compute = RateMeter(start_ns), []

    def receive_setpoint(self, stamp_ns: int, setpoint: Setpoint, tag: Any = None) -> None:
        """Queue a setpoint stamped stamp_ns, O(1); the first tick after the stamp activates it
        unless a newer one supersedes it. A full intake drops its oldest setpoint (superseded)."""
        self.counters.received_setpoints += 1
        if len(self._intake) == SETPOINT_INTAKE:
            self._intake.popleft()
            self.counters.superseded_setpoints += 1
        self._intake.append((stamp_ns, setpoint, tag))

    def drop_setpoints(self, count: int) -> None:
        """count setpoints were received and replaced by newer ones before they were handed in (a
        caller that keeps only the newest SETPOINT_INTAKE undecoded messages between ticks): counted
        as received and superseded."""
        self.counters.received_setpoints += count
        self.counters.superseded_setpoints += count

    def refuse_setpoint(self, text: str) -> None:
        """A setpoint that arrived but could not be read (e.g. malformed CDR): received and refused
        as undecodable, ``text`` saying why; the active setpoint stays."""
        self.counters.received_setpoints += 1
        self._refused(Refusal(SetpointRejection.UNDECODABLE, text))

    @property
    def pending_setpoints(self) -> int:
        """Setpoints received and not yet checked (at most SETPOINT_INTAKE)."""
        return len(self._intake)

    def state(
        self,
        stamp_ns: int,
        now_ns: int,
        q: ArrayLike,
        q_dot: ArrayLike,
        chiee: ArrayLike,
        chiee_dot: ArrayLike,
        velocity_valid: bool = True,
    ) -> Refusal | None:
        """A measured state: why it is refused (counted), or None; only accepted ones with valid
        velocities are used."""
        problem = state_problem(self._q_bounds, q, q_dot, chiee, chiee_dot, velocity_valid)
        if problem is None and velocity_valid:
            problem = self.supervisor.state(stamp_ns, now_ns)
            if problem is None:
                self._newest = (stamp_ns, Measurement(q, q_dot, chiee, chiee_dot))
        if problem is not None:
            self.rejections.states[problem.reason] += 1
            self.rejections.last_state = problem
        return problem

    def heartbeat(self, now_ns: int) -> None:
        """The driver showed it is alive."""
        self.supervisor.driver_heartbeat(now_ns)

    def driver_torque(self, on: bool) -> bool:
        """Whether the driver's servos take commands (torque on); True when it changed."""
        return self.supervisor.driver_torque(on)

    def set_estop(self, active: bool) -> bool:
        """E-stop state from the driver; True when it changed. Entering it resets the integrators,
        drops the hold."""
        if active == self.supervisor.estop:
            return False
        if self.supervisor.set_estop(active):
            self.controller.reset()
            self._held = None
            self.counters.estop_events += 1
        return True

    def tick(self, now_ns: int) -> Tick:
        """One control period at now_ns: activate due setpoints, then step, re-send the held command
        or send nothing."""
        self._count(now_ns)
        activated = self._activate(now_ns)
        decision = self.supervisor.tick(now_ns)
        if decision.action is Action.STEP:
            return self._step(now_ns, decision, activated)
        if decision.action is Action.HOLD and self._held is not None:
            self.counters.held_ticks += 1
            return Tick(
                decision,
                Mode.HOLD,
                Action.HOLD,
                self._held,
                transition=self._enter(Mode.HOLD, now_ns),
                activated=activated,
            )
        mode = Mode.STALE if decision.action is Action.HOLD else decision.mode  # nothing to hold
        return Tick(
            decision, mode, Action.NONE, transition=self._enter(mode, now_ns), activated=activated
        )

    def period(self, now_ns: int) -> Period:
        """The reporting period ending at now_ns (tick rate, compute times); the next one starts
        now."""
        period = Period(
            self._rate.rates(now_ns, {"ticks": self.counters.ticks})["ticks"],
            tuple(self._window_compute),
        )
        self._window_compute = []
        return period

    def _count(self, now_ns: int) -> None:
        """Tick counters and deadline misses (tick interval > DEADLINE_FACTOR periods)."""
        if (
            self._last_tick is not None
            and (now_ns - self._last_tick) * 1e-9 > DEADLINE_FACTOR * self.controller.dt
        ):
            self.counters.deadline_misses += 1
        self._last_tick = now_ns
        self.counters.ticks += 1

    def _activate(self, now_ns: int) -> tuple[Activation, ...]:
        """Activate the newest setpoint stamped before now_ns that passes the checks (at most
        SETPOINT_CHECKS tried, newest first); returns the tried ones in arrival order. Refusals are
        counted, the untried due ones superseded.
        """
        due = [entry for entry in self._intake if entry[0] < now_ns]
        if not due:
            return ()
        self._intake = deque(entry for entry in self._intake if entry[0] >= now_ns)
        tried: list[Activation] = []
        for _, setpoint, tag in reversed(due[-SETPOINT_CHECKS:]):
            problem = self._problem(setpoint)
            tried.append(Activation(tag, problem))
            if problem is None:
                self.active_tag = tag
                self.supervisor.setpoint_accepted()
                self.counters.setpoints += 1
                break
        self.counters.superseded_setpoints += len(due) - len(tried)
        tried.reverse()
        for activation in tried:
            if activation.problem is not None:
                self._refused(activation.problem)
        return tuple(tried)

    def _refused(self, problem: Refusal) -> None:
        """Count a refused setpoint under its reason."""
        self.counters.rejected_setpoints += 1
        self.rejections.setpoints[problem.reason] += 1
        self.rejections.last_setpoint = problem

    def _problem(self, setpoint: Setpoint) -> Refusal | None:
        """Why a setpoint is refused (physical check, then the law's own checks), or None: it is
        active now."""
        problem = self._check(setpoint) if self._check is not None else None
        if problem is None:
            try:
                self.controller.set_setpoint(setpoint)
            except ValueError as exc:
                problem = Refusal(SetpointRejection.LAW, str(exc))
        return problem

    def _step(self, now_ns: int, decision: Decision, activated: tuple[Activation, ...]) -> Tick:
        """Step the law on the newest state; its command is held from now on. A refusal sends
        nothing."""
        stamp_ns, measurement = self._newest  # the supervisor steps only with a state
        t0 = time.perf_counter()
        try:
            phi, info = self.controller.step(*measurement)
        except ValueError as exc:
            self.counters.refused_ticks += 1
            return Tick(decision, self.mode, Action.NONE, refused=str(exc), activated=activated)
        compute_s = time.perf_counter() - t0
        self._window_compute.append(compute_s)
        self.counters.saturated += int(info.saturated)
        self._held = Command(np.asarray(phi, dtype=np.float64), stamp_ns)
        self._tracked_at = now_ns
        return Tick(
            decision,
            Mode.TRACKING,
            Action.STEP,
            self._held,
            info,
            measurement,
            compute_s,
            transition=self._enter(Mode.TRACKING, now_ns),
            activated=activated,
        )

    def _enter(self, mode: Mode, now_ns: int) -> Transition | None:
        """Record the tick's mode; on a change count it and return it (with the outage on a return
        to tracking)."""
        if mode is self.mode:
            return None
        old, self.mode = self.mode, mode
        outage = math.nan
        if old is Mode.TRACKING:
            self._lost_at = self._tracked_at
        if mode is Mode.TRACKING and self._lost_at is not None:
            outage = self.last_outage_s = (now_ns - self._lost_at) * 1e-9
            self._lost_at = None
        elif mode is Mode.HOLD:
            self.counters.stale_events += 1
        elif mode is Mode.STALE:
            self.counters.stale_stops += 1
        elif mode is Mode.DRIVER_LOST:
            self.counters.driver_lost_events += 1
        elif mode is Mode.TORQUE_OFF:
            self.counters.torque_off_events += 1
        return Transition(old, mode, outage)

"""Lockstep playback decisions (no ROS): when a bag player may publish its next message and move
/clock.

A player in lockstep owns /clock and plays a bag's messages in log-time order.
:class:`LockstepPlayback` is its state machine; the player feeds it the playback time of the next
message and the wall time, and acts on each :class:`Step`:

* ``start``: simulated time does not start before
  :meth:`hsa_core.sim.lockstep.Barrier.start_problem` is None, the player's own publishers (/clock
  included) being the simulator's (nothing the player publishes may go to a subscription that does
  not know it yet);
* an **instant** is the log time of the next message, or an earlier timer due of a participant (so
  timers run at the instants they were due at, as in the recorded run); the first instant is the
  first message's log time. Before the clock moves to a new instant, everything published must be
  taken (``settle_problem``); where a timer is due, the participants that log in simulated time (a
  recorder) get the instant with the counts that precede it (``lead``;
  :class:`hsa_core.sim.lockstep.LogTimes`), and without waiting /clock is published (``clock``);
  the instant must then be finished (``finish_problem``: settled, every timer due there has run,
  those participants' clocks at the instant); /clock is sent again every ``resend`` s while that
  waits (it is best effort);
* a message whose log time is the current instant is published (``publish``); after the last one the
  graph must settle once more (``done``);
* waiting longer than ``timeout`` s of wall time in one instant (10 × ``timeout`` for the start) is
  a failure (``fail``, naming what holds the barrier).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

from hsa_core.sim.lockstep import Barrier

START, MOVE, LEAD, FINISH, OVER = "start", "move", "lead", "finish", "over"


class Action(enum.StrEnum):
    """What a lockstep coordinator does now (a player: :class:`LockstepPlayback`; the simulator:
    :class:`hsa_core.sim.sim_lockstep.SimLockstep`); values are the names in the docs."""

    WAIT = "wait"  # the barrier holds: ``reason`` says why
    START = "start"  # simulated time starts (simulator)
    RUN = "run"  # run the world to ``t_ns``, no /clock (simulator)
    INSTANT = "instant"  # run the world to the instant ``t_ns``, which must then settle (simulator)
    LEAD = "lead"  # publish ``t_ns`` and Barrier.leads() on the lead topic
    CLOCK = "clock"  # publish /clock at ``t_ns`` (with a ``reason``: resent, the barrier holds)
    FINISH = "finish"  # the instant ``t_ns`` is finished (simulator)
    PUBLISH = "publish"  # the next message (player); the samples run to, up to ``t_ns`` (simulator)
    STOP = "stop"  # an expected participant left: simulated time stops (simulator)
    DONE = "done"  # nothing more to do
    FAIL = "fail"  # a wait took too long: ``reason`` names what holds the barrier


@dataclass(frozen=True)
class Step:
    """What the coordinator does now (:class:`Action`) at ``t_ns``; ``reason`` says what holds the
    barrier (wait, fail, a resent clock)."""

    action: Action
    t_ns: int | None = None
    reason: str = ""


class LockstepPlayback:
    """The player's side of the lockstep barrier; see the module docstring. Times: ns of playback
    time, s of wall."""

    def __init__(self, barrier: Barrier, timeout: float, resend: float = 0.05) -> None:
        self.barrier = barrier
        self.timeout = timeout
        self.resend = resend
        self.phase = START
        self.instant: int | None = None  # the instant the graph is working on
        self._since: float | None = None  # wall time the current wait began
        self._clock_sent = 0.0

    def step(self, next_ns: int | None, matched: Mapping[str, int], now: float) -> Step:
        """The next action, given the next message's playback time (None: none left), the player's
        matched subscription counts per published topic (/clock included), and the wall time
        ``now``."""
        if self._since is None:
            self._since = now
        if self.phase == START:
            self.barrier.own_matched = dict(matched)
            problem = self.barrier.start_problem(now)
            if problem is not None:
                return self._wait(problem, now, 10 * self.timeout)
            self.barrier.start()
            self._progress(MOVE, now)
        if self.phase == FINISH:
            assert self.instant is not None
            problem = self.barrier.finish_problem(self.instant)
            if problem is not None:
                failed = self._wait(problem, now, self.timeout)
                if failed.action is Action.WAIT and now - self._clock_sent >= self.resend:
                    self._clock_sent = now
                    return Step(Action.CLOCK, self.instant, problem)
                return failed
            self._progress(MOVE, now)
        if self.phase == LEAD:  # the lead is out: /clock follows at once
            return self._move_clock(now)
        if self.phase == MOVE:
            if next_ns is not None and self.instant is not None and next_ns <= self.instant:
                self._progress(MOVE, now)
                return Step(Action.PUBLISH, self.instant)
            problem = self.barrier.settle_problem()
            if problem is not None:
                return self._wait(problem, now, self.timeout)
            if next_ns is None:
                self.phase = OVER
                return Step(Action.DONE, self.instant)
            due = self.barrier.next_due_ns()
            if self.instant is not None and due is not None and self.instant < due < next_ns:
                next_ns = due
            self.instant = next_ns
            if due is not None and due <= next_ns and self.barrier.needs_lead():
                self._progress(LEAD, now)
                return Step(Action.LEAD, self.instant)
            return self._move_clock(now)
        return Step(Action.DONE, self.instant)

    def _move_clock(self, now: float) -> Step:
        """/clock moves to the instant, which must then finish."""
        self._progress(FINISH, now)
        self._clock_sent = now
        return Step(Action.CLOCK, self.instant)

    def _progress(self, phase: str, now: float) -> None:
        """Enter ``phase``; the wait for it starts now."""
        self.phase = phase
        self._since = now

    def _wait(self, problem: str, now: float, limit: float) -> Step:
        """Wait for ``problem`` to clear, or fail once the current wait is longer than ``limit``
        s."""
        assert self._since is not None
        waited = now - self._since
        if waited <= limit:
            return Step(Action.WAIT, self.instant, problem)
        where = (
            "before simulated time started"
            if self.phase == START
            else f"at t = {(self.instant or 0) * 1e-9:.3f} s"
        )
        return Step(
            Action.FAIL,
            self.instant,
            f"lockstep barrier {where} not finished after {waited:.1f} s of wall time: {problem}",
        )

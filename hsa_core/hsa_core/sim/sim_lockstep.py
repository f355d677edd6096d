"""The simulator's lockstep decisions (no ROS): when the world moves on, when /clock moves, when an
instant is over.

sim_node owns /clock in a lockstep graph (docs/simulation.md) and runs the world
(:class:`hsa_core.sim.world.World`) from event to event. :class:`SimLockstep` is its state machine;
the node feeds it the world's time, when the next mocap sample becomes available and whether the
emulated bus is idle, and acts on each :class:`~hsa_core.sim.playback.Step`:

* ``start``: simulated time starts (:meth:`hsa_core.sim.lockstep.Barrier.start_problem` is None, the
  simulator's own publishers, /clock included, counted as ``matched``); until then /clock at 0 is
  sent again every ``resend`` s;
* ``run`` to t: the next event is a sample becoming available; run the world to t (no /clock:
  data callbacks keep the clock of the last timer instant). The samples of consecutive runs go out
  together (``publish`` t: those run to, up to t) before the next instant or stop, in one burst
  rather than one by one between world steps;
* ``instant`` t: the next event is a participant's timer due, or ``sync_ns`` of simulated time have
  passed since the last instant; run the world to t. The graph must then settle (take everything
  published); at a timer due the participants that log in simulated time get t with the counts
  that precede it (``lead`` t, when :meth:`~hsa_core.sim.lockstep.Barrier.needs_lead`;
  :class:`~hsa_core.sim.lockstep.LogTimes`), and without waiting the clock moves (``clock`` t);
  the instant must then finish (``finish_problem``, their clocks at t included, and the bus has
  executed every packet it received), /clock being sent again every ``resend`` s while that waits
  (it is best effort); then ``finish`` t: the bus writes reach the world at t and the samples
  available at t are published;
* ``stop``: an expected participant has left, the graph is ending: simulated time stops (``done``
  thereafter);
* ``fail``: one wait took longer than ``timeout`` s of wall time (``start_timeout``, if longer,
  before the start).

This is not :class:`hsa_core.sim.playback.LockstepPlayback`: a player moves /clock to every
message's log time, while the simulator publishes samples between clock instants and moves /clock
only where a timer is due.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from hsa_core.sim.lockstep import Barrier
from hsa_core.sim.playback import Action, Step

START, ADVANCE, SETTLE, LEAD, FINISH = "start", "advance", "settle", "lead", "finish"
SYNC_NS = 50_000_000
"""[ns] the graph must have taken every sample at least every 50 ms of simulated time."""
START_TIMEOUT = 180.0
"""[s] of wall time simulated time may wait to start (planner compilation on a busy machine)."""
BUS_BUSY = "the emulated bus has not executed every packet it received"


class SimLockstep:
    """The simulator's side of the lockstep barrier; see the module docstring. Times: ns simulated,
    s of wall."""

    def __init__(
        self,
        barrier: Barrier,
        timeout: float,
        resend: float = 0.05,
        sync_ns: int = SYNC_NS,
        start_timeout: float = START_TIMEOUT,
    ) -> None:
        self.barrier = barrier
        self.timeout = timeout
        self.resend = resend
        self.sync_ns = sync_ns
        self.start_timeout = start_timeout
        self.phase = START
        self.instant = 0  # [ns] the instant the graph is working on
        self._since: float | None = None  # wall time the current wait began
        self._clock_sent = 0.0
        self._synced = 0
        self._halted = False
        self._ran: int | None = None  # [ns] run to here, the samples not yet published

    def step(
        self,
        now: float,
        world_ns: int,
        next_sample_ns: int,
        bus_idle: Callable[[], bool],
        matched: Callable[[], Mapping[str, int]],
    ) -> Step:
        """The next action, given the wall time ``now``, the world's time, when its next sample
        becomes available, whether the bus is idle and the simulator's matched subscription counts
        per published topic (the last two asked only when needed: they cost a system call and a
        graph query)."""
        if self._since is None:
            self._since = now
        if self.barrier.left:
            if self._ran is not None:
                return self._publish()
            if self._halted:
                return Step(Action.DONE, self.instant)
            self._halted = True
            return Step(Action.STOP, self.instant, f"{self.barrier.left[0]} left")
        if self.phase == START:
            self.barrier.own_matched = dict(matched())
            problem = self.barrier.start_problem(now)
            if problem is not None:
                return self._wait(problem, now, send_clock=True)
            self.barrier.start()
            self.phase = ADVANCE
            return Step(Action.START, self.instant)
        if self.phase == SETTLE:
            problem = self.barrier.settle_problem()
            if problem is not None:
                return self._wait(problem, now)
            self._since = now
            if world_ns == self.instant and self.instant == self.barrier.next_due_ns():
                if self.barrier.needs_lead():
                    self.phase = LEAD
                    return Step(Action.LEAD, self.instant)
                return self._move_clock(now)
            self.phase = ADVANCE
        if self.phase == LEAD:  # the lead is out: /clock follows at once
            return self._move_clock(now)
        if self.phase == FINISH:
            problem = self.barrier.finish_problem(self.instant)
            if problem is None and not bus_idle():
                problem = BUS_BUSY
            if problem is not None:
                return self._wait(problem, now, send_clock=True)
            self.phase = ADVANCE
            return Step(Action.FINISH, self.instant)
        return self._advance(now, next_sample_ns)

    def _move_clock(self, now: float) -> Step:
        """/clock moves to the instant, which must then finish."""
        self.phase = FINISH
        self._clock_sent = now
        return Step(Action.CLOCK, self.instant)

    def _advance(self, now: float, next_sample_ns: int) -> Step:
        """The next event: a sample becoming available (``run``), or an instant the graph must
        settle at."""
        due = self.barrier.next_due_ns()
        event = next_sample_ns if due is None else min(due, next_sample_ns)
        if event - self._synced >= self.sync_ns or (due is not None and event == due):
            if self._ran is not None:
                return self._publish()
            self._synced = event
            self.instant = event
            self.phase = SETTLE
            self._since = now
            return Step(Action.INSTANT, event)
        self._ran = event
        return Step(Action.RUN, event)

    def _publish(self) -> Step:
        """The samples of the runs since the last instant go out together."""
        t_ns, self._ran = self._ran, None
        return Step(Action.PUBLISH, t_ns)

    def _wait(self, problem: str, now: float, send_clock: bool = False) -> Step:
        """Resend /clock if it may have been lost (a ``clock`` step with a reason); else wait, or
        fail once the current wait is longer than the limit."""
        assert self._since is not None
        if send_clock and now - self._clock_sent > self.resend:
            self._clock_sent = now
            return Step(Action.CLOCK, self.instant, problem)
        waited = now - self._since
        limit = self.timeout if self.phase != START else max(self.start_timeout, self.timeout)
        if waited > limit:
            return Step(
                Action.FAIL,
                self.instant,
                f"lockstep barrier at t = {self.instant * 1e-9:.3f} s not finished "
                f"after {waited:.1f} s of wall time: {problem}",
            )
        return Step(Action.WAIT, self.instant, problem)

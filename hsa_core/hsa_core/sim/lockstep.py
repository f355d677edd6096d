"""The lockstep barrier's decisions (no ROS): when simulated time may start, and when an instant is
finished.

Participants are the nodes of a simulated graph. Each reports (``Report``) whenever it has run every
ready callback: its ROS time, whether it is ready (publishers matched, service clients connected),
its earliest timer, the service requests it awaits, and per topic how many messages it has published
and taken since start. The simulator's own publications are counted in the same way. From the latest
report of every participant the barrier decides:

* ``discovery_problem()`` — every expected participant has reported, is ready, and discovery is
  complete on both sides of every topic (None): each publisher (a participant's or the simulator's
  own, ``own_matched``, /clock included) has matched at least as many subscriptions as participants
  subscribe to its topic, and each participant's subscriptions have matched at least as many
  publishers as participants and the simulator have on it (``heard``). DDS matches the two ends
  separately: a writer that knows a reader sends to it, but a reader that does not know the writer
  yet drops what arrives, so one side alone loses the first messages;
* ``start_problem(now)`` — simulated time may start (None) once discovery has stayed complete, with
  the same match counts, for ``DISCOVERY_SETTLE`` s of wall time: a best-effort sample sent in the
  first milliseconds after both ends matched can still be lost (seen at the start of a replay: a
  recorder took none of the first four states published 9 ms after its subscription matched);
* ``settle_problem()`` — nothing is in flight (None): on every topic, every participant that takes
  it has taken every message published on it, and no service request is unanswered;
* ``lead_problem(t)`` — every participant with ``clock_acks`` (a recorder, whose log times are its
  clock) has reported a clock at t (None). /clock and an instant's messages travel on different
  topics, so a loaded machine can deliver a message before the clock of its instant: where a timer
  is due the coordinator sends these participants a lead (``leads``: t, and per participant the
  counts it had taken when the graph settled, all that precedes t) together with /clock, and
  :class:`LogTimes` gives each message the instant it belongs to (``needs_lead``: some have
  joined);
* ``finish_problem(t)`` — instant t is finished (None): settled, no participant has a timer due at
  or before t left to run (a participant reports a new earliest timer once it ran the due ones; one
  that only saw the clock move need not report), and the ``clock_acks`` participants are at t
  (``lead_problem``).

Message counting detects messages in flight between processes without any assumption on delivery
order: a participant reports only after its callbacks ran, so every message it published is counted
before the report that would hide it arrives. A participant that joins after the start is taken as
settled at its first report (its subscriptions cannot have received what was published before they
existed); one that leaves is dropped, and once an expected participant has left (``left``) the graph
is ending. Every ``*_problem`` method returns a one-line reason naming the participants and topics
that hold the barrier.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

DISCOVERY_SETTLE = 0.5
"""[s] of wall time discovery must stay complete and unchanged before simulated time starts."""


@dataclass(frozen=True)
class Report:
    """One participant's report; times in ns of ROS time (``next_due_ns`` None: no timer)."""

    node: str
    clock_ns: int
    ready: bool = True
    leaving: bool = False
    next_due_ns: int | None = None
    pending: int = 0
    published: Mapping[str, int] = field(default_factory=dict)
    matched: Mapping[str, int] = field(default_factory=dict)
    taken: Mapping[str, int] = field(default_factory=dict)
    # per subscribed topic (/clock too): publishers matched
    heard: Mapping[str, int] = field(default_factory=dict)
    # it reports every clock move; an instant waits for its clock (a recorder's log times)
    clock_acks: bool = False


class Barrier:
    """Latest report per participant and the simulator's own counts; see the module docstring."""

    def __init__(self, expected: Iterable[str] = ()) -> None:
        self.expected = tuple(expected)
        self.reports: dict[str, Report] = {}
        self.own: dict[str, int] = {}  # the simulator's publications per topic
        self.own_matched: dict[
            str, int
        ] = {}  # the simulator's publishers (/clock too): subscriptions matched
        self.started = False
        self._discovered: tuple[tuple, float] | None = None  # (match counts, since) once complete
        self.left: list[str] = []  # expected participants that have left: the graph is ending
        self._baseline: dict[
            str, dict[str, int]
        ] = {}  # late joiner: taken offset per topic at its first report

    def report(self, report: Report) -> None:
        """Take a participant's newest report (a leaving participant is dropped)."""
        if report.leaving:
            self.reports.pop(report.node, None)
            if report.node in self.expected and report.node not in self.left:
                self.left.append(report.node)
            return
        if self.started and report.node not in self.reports and report.node not in self._baseline:
            totals = self.published_totals()
            self._baseline[report.node] = {t: totals.get(t, 0) - n for t, n in report.taken.items()}
        self.reports[report.node] = report

    def published_totals(self) -> dict[str, int]:
        """Messages published per topic by every participant and the simulator."""
        totals = dict(self.own)
        for r in self.reports.values():
            for topic, n in r.published.items():
                totals[topic] = totals.get(topic, 0) + n
        return totals

    def start_problem(self, now: float) -> str | None:
        """Why simulated time cannot start yet at wall time ``now`` [s], or None."""
        problem = self.discovery_problem()
        if problem is not None:
            self._discovered = None
            return problem
        counts = (
            tuple(sorted(self.own_matched.items())),
            tuple(
                (n, tuple(sorted(r.matched.items())), tuple(sorted(r.heard.items())))
                for n, r in sorted(self.reports.items())
            ),
        )
        if self._discovered is None or self._discovered[0] != counts:
            self._discovered = (counts, now)
        waited = now - self._discovered[1]
        if waited < DISCOVERY_SETTLE:
            return f"discovery complete {waited:.3f} s ago, settling for {DISCOVERY_SETTLE} s"
        return None

    def discovery_problem(self) -> str | None:
        """Why discovery is not complete yet (participants, readiness, both ends of every topic),
        or None."""
        missing = [n for n in self.expected if n not in self.reports]
        if missing:
            return f"waiting for participants {missing}"
        unready = sorted(n for n, r in self.reports.items() if not r.ready)
        if unready:
            return f"participants not ready (publishers unmatched or services missing): {unready}"
        takers: dict[str, int] = {}  # participants subscribed per topic
        # publishers per topic: the simulator's ...
        writers: dict[str, int] = {t: 1 for t in self.own_matched}
        for r in self.reports.values():
            for topic in r.heard.keys() | r.taken.keys():
                takers[topic] = takers.get(topic, 0) + 1
            for topic in r.matched:  # ... and the participants'
                writers[topic] = writers.get(topic, 0) + 1
        pubs = [(r.node, r.matched) for r in self.reports.values()] + [
            ("simulator", self.own_matched)
        ]
        for node, matched in pubs:
            for topic, n in sorted(matched.items()):
                if n < takers.get(topic, 0):
                    return (
                        f"{node}: '{topic}' matched {n} of {takers[topic]} participant "
                        "subscriptions"
                    )
        for r in self.reports.values():
            for topic, n in sorted(r.heard.items()):
                if n < writers.get(topic, 0):
                    return (
                        f"{r.node}: subscription to '{topic}' matched {n} of {writers[topic]} "
                        "publishers"
                    )
        return None

    def start(self) -> None:
        """Simulated time starts: later joiners are taken as settled at their first report."""
        self.started = True

    def settle_problem(self) -> str | None:
        """What is still in flight, or None."""
        totals = self.published_totals()
        for r in self.reports.values():
            if r.pending:
                return f"{r.node} awaits {r.pending} service answer(s)"
            base = self._baseline.get(r.node, {})
            for topic, taken in r.taken.items():
                published = totals.get(topic, 0)
                if topic in totals and taken + base.get(topic, 0) < published:
                    return (
                        f"{r.node} has taken {taken + base.get(topic, 0)} of {published} messages "
                        f"on '{topic}'"
                    )
        return None

    def finish_problem(self, t_ns: int) -> str | None:
        """What keeps instant ``t_ns`` from being finished, or None."""
        due = sorted(
            n
            for n, r in self.reports.items()
            if r.next_due_ns is not None and r.next_due_ns <= t_ns
        )
        if due:
            return f"timers due at {t_ns} ns not yet run by {due}"
        return self.lead_problem(t_ns) or self.settle_problem()

    def needs_lead(self) -> bool:
        """Whether some participant reports its clock (``clock_acks``): /clock then waits for the
        lead clock."""
        return any(r.clock_acks for r in self.reports.values())

    def lead_problem(self, t_ns: int) -> str | None:
        """Which ``clock_acks`` participants have not reported a clock at ``t_ns`` yet, or None."""
        behind = sorted(n for n, r in self.reports.items() if r.clock_acks and r.clock_ns < t_ns)
        return f"clock of {behind} not yet at {t_ns} ns" if behind else None

    def leads(self) -> dict[str, Mapping[str, int]]:
        """Per ``clock_acks`` participant, the counts it reported taken (its own, as reported): sent
        with an instant's lead once the graph has settled, they are every message that precedes
        the instant."""
        return {n: r.taken for n, r in self.reports.items() if r.clock_acks}

    def next_due_ns(self) -> int | None:
        """The earliest timer of any participant, or None."""
        dues = [r.next_due_ns for r in self.reports.values() if r.next_due_ns is not None]
        return min(dues) if dues else None


class ReportPacing:
    """When a participant reports (the runner's lockstep spin): as soon as no callback is ready
    after one ran (a poll), then again after every ``period`` of waiting without work. A report
    shows the counts at the moment it is made, so a later one is never less true."""

    def __init__(self, period: float = 0.02) -> None:
        self.period = period
        self.idle = False  # reported since the last callback: wait a period at a time for work

    def timeout(self) -> float:
        """[s] how long the executor may wait for a ready callback now."""
        return self.period if self.idle else 0.0

    def ran(self) -> None:
        """A callback ran: poll for the next one, and report if none is ready."""
        self.idle = False

    def timed_out(self) -> None:
        """No callback was ready within :meth:`timeout` (at once after a callback, or within a
        period while idle): the participant reports now, and waits a period for work from then
        on."""
        self.idle = True


@dataclass
class _Held:
    """A message taken, not yet logged: its topic, its count on the topic, its log time so far."""

    topic: str
    count: int
    t_ns: int
    write: Callable[[int], None]


class LogTimes:
    """A recorder's log times in lockstep, without a round trip before /clock.

    A message's log time is the clock of the instant it was published in. A message taken while the
    recorder's clock is at an instant may still belong to the next one (a timer's message can arrive
    before its /clock and lead), so each is held (``take``: its topic, its count on the topic as the
    participant counts it, the clock now, and how to write it) until the next lead (``lead``: the
    instant t and the counts taken before it): one counted within those precedes t and is written at
    the time it was taken; a later one belongs to t or after (its time becomes at least t) and waits
    for the following lead. ``flush`` writes what is left (the end of the run).
    """

    def __init__(self) -> None:
        self._held: deque[_Held] = deque()

    def take(self, topic: str, count: int, now_ns: int, write: Callable[[int], None]) -> None:
        """Hold message ``count`` of ``topic``, taken at ``now_ns``, until its instant is known."""
        self._held.append(_Held(topic, count, now_ns, write))

    def lead(self, t_ns: int, taken: Mapping[str, int]) -> None:
        """Instant ``t_ns`` begins after ``taken`` messages per topic: write those, in the order
        taken; the others are at least at ``t_ns``."""
        kept: deque[_Held] = deque()
        for held in self._held:
            if held.count <= taken.get(held.topic, 0):
                held.write(held.t_ns)
            else:
                held.t_ns = max(held.t_ns, t_ns)
                kept.append(held)
        self._held = kept

    def flush(self) -> None:
        """Write every message held, at its time so far (no later instant will come)."""
        while self._held:
            held = self._held.popleft()
            held.write(held.t_ns)

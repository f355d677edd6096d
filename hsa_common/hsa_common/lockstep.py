"""A node's side of the lockstep barrier: count what it publishes and takes, and report when it runs
out of work.

``Participant(node)`` wraps the node's publishers, subscriptions, service servers and clients to
count messages per topic (services as ``srv:<name>``; /clock, /rosout, /parameter_events, the
barrier's own topic and the node's private parameter/lifecycle services are not counted), and
publishes an ``hsa_msgs/LockstepAck`` on ``ACK_TOPIC`` when the runner has found no callback ready
for a moment (:func:`hsa_common.runner.run`, :class:`hsa_core.sim.lockstep.ReportPacing`). The
decisions are in :mod:`hsa_core.sim.lockstep`; the contract is in docs/simulation.md. A node may add
a readiness condition with a ``lockstep_ready() -> bool`` method (the recorder: every selected topic
subscribed). A node whose log times are simulated time (the recorder) reads them from a
:class:`LeadClock` kept as its ``lockstep_clock``: the coordinator sends each timer instant there
before /clock moves, and the participant reports every move of that clock, so nothing a timer
publishes at t reaches the node before its clock is at t.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from typing import Any, Protocol

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.timer import Timer
from rosgraph_msgs.msg import Clock as ClockMsg

from hsa_common import convert
from hsa_core.sim.lockstep import Report
from hsa_msgs.msg import LockstepAck

ACK_TOPIC = "/_lockstep/ack"
"""Hidden topic of the participants' reports (not recorded)."""
ACK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Reports: only a participant's latest matters (they are cumulative); transient local, so a
simulator that starts after a participant still gets its report."""
ACK_READER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""The simulator's subscription: deep enough for a burst of reports from every participant."""
LEAD_TOPIC = "/_lockstep/lead"
"""Hidden topic of the lead clock: each timer instant, sent to the nodes with a :class:`LeadClock`
before /clock."""
LEAD_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Only the latest instant matters; reliable, as the coordinator sends each one once and waits for
the reports."""
UNCOUNTED = frozenset({"/clock", "/rosout", "/parameter_events", ACK_TOPIC, LEAD_TOPIC})
UNWATCHED = UNCOUNTED - {"/clock", LEAD_TOPIC}
"""Topics whose discovery does not hold the start (every other subscription, the clocks included,
must be matched)."""
UNMATCHED = 2**32 - 1  # LockstepAck.matched of a service client (its readiness is service_is_ready)


def wall_timer(node: Node, period: float, callback: Any) -> Timer:
    """A timer on the steady clock, outside the barrier (graph discovery, wall-clock
    supervision)."""
    timer = node.create_timer(period, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))
    timer.lockstep_wall = True  # read by Participant.report: not a timer of simulated time
    return timer


def enabled(node: Node) -> bool:
    """Whether the node runs in lockstep: parameter ``lockstep`` (declared here if the node did not)
    is true."""
    if not node.has_parameter("lockstep"):
        node.declare_parameter("lockstep", False)
    return bool(node.get_parameter("lockstep").value)


class LeadClock:
    """A node's simulated time for logging: the node clock, or the lead clock's instant if that is
    ahead (lockstep)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.lead_ns = 0
        if enabled(node):
            node.create_subscription(ClockMsg, LEAD_TOPIC, self._lead, LEAD_QOS)

    def _lead(self, msg: ClockMsg) -> None:
        self.lead_ns = max(self.lead_ns, convert.stamp_ns(msg.clock))

    def now_ns(self) -> int:
        """[ns] the later of the node clock and the latest lead instant."""
        return max(self.node.get_clock().now().nanoseconds, self.lead_ns)


class Reporter(Protocol):
    """What the runner's lockstep spin needs: a report whenever the process has run out of work."""

    def idle(self, leaving: bool = False) -> None:
        """The process found nothing to run (``leaving``: it stops): report if anything changed."""


class Participant:
    """Counts a node's traffic and reports to the lockstep simulator; see the module docstring."""

    def __init__(self, node: Node, publish_acks: bool = True) -> None:
        self.node = node
        self.published: Counter[str] = Counter()
        self.taken: Counter[str] = Counter()
        self.pending = 0
        # a recorder: instants wait for it
        self.lead_clock: LeadClock | None = getattr(node, "lockstep_clock", None)
        self.clock_acks = self.lead_clock is not None
        self._wrapped: set[int] = set()
        self._pubs: dict[str, list[Any]] = {}
        self._last: tuple | None = None
        self._ready: bool | None = None
        self._matched: dict[str, int] = {}
        self._heard: dict[str, int] = {}
        self._ack_pub = (
            node.create_publisher(LockstepAck, ACK_TOPIC, ACK_QOS) if publish_acks else None
        )
        self._since: set[str] = set()  # topics taken since the last report
        self.triggers: Counter[str] = Counter()  # reports per cause (topics taken, timer, clock)
        self.instrument()

    def instrument(self) -> None:
        """Wrap every publisher, subscription, service and client not wrapped yet (nodes may create
        them later)."""
        for pub in self.node.publishers:
            topic = pub.topic_name
            if id(pub) in self._wrapped or topic in UNCOUNTED:
                continue
            self._wrapped.add(id(pub))
            self._pubs.setdefault(topic, []).append(pub)
            self.published.setdefault(topic, 0)
            pub.publish = self._counting(pub.publish, self.published, topic)
        for sub in self.node.subscriptions:
            if id(sub) in self._wrapped or sub.topic_name in UNCOUNTED:
                continue
            self._wrapped.add(id(sub))
            self.taken.setdefault(sub.topic_name, 0)
            sub.callback = self._counting(sub.callback, self.taken, sub.topic_name, self._since)
        # parameter, lifecycle and type services of the node
        private = self.node.get_fully_qualified_name() + "/"
        for srv in self.node.services:
            if id(srv) in self._wrapped:
                continue
            self._wrapped.add(id(srv))
            resolved = self.node.resolve_service_name(srv.srv_name)
            if resolved.startswith(private):
                continue
            name = f"srv:{resolved}"
            self.taken.setdefault(name, 0)
            srv.callback = self._counting(srv.callback, self.taken, name, self._since)
        for client in self.node.clients:
            if id(client) in self._wrapped:
                continue
            self._wrapped.add(id(client))
            name = f"srv:{self.node.resolve_service_name(client.srv_name)}"
            self.published.setdefault(name, 0)
            client.call_async = self._calling(client.call_async, name)

    @staticmethod
    def _counting(fn: Any, counter: Counter[str], topic: str, since: set[str] | None = None) -> Any:
        def counted(*args: Any, **kwargs: Any) -> Any:
            counter[topic] += 1
            if since is not None:
                since.add(topic)
            return fn(*args, **kwargs)

        return counted

    def _calling(self, call_async: Any, topic: str) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            self.published[topic] += 1
            self.pending += 1
            future = call_async(*args, **kwargs)
            future.add_done_callback(self._answered)
            return future

        return call

    def _answered(self, _future: Any) -> None:
        self.pending -= 1

    def report(self, leaving: bool = False) -> Report:
        """The node's state now, as the barrier sees it."""
        self.instrument()
        now = self.node.get_clock().now().nanoseconds
        dues = []
        for timer in self.node.timers:
            if getattr(timer, "lockstep_wall", False) or timer.is_canceled():
                continue
            remaining = timer.time_until_next_call()
            if remaining is not None:
                dues.append(now + remaining)
        if (
            now == 0 or self._ready is None
        ):  # readiness only matters before simulated time starts: graph queries cost
            hook = getattr(self.node, "lockstep_ready", None)
            self._ready = all(c.service_is_ready() for c in self.node.clients) and (
                hook is None or bool(hook())
            )
            self._matched = {
                t: min(p.get_subscription_count() for p in pubs) for t, pubs in self._pubs.items()
            }
            self._heard = heard(self.node)
        clock_ns = now if self.lead_clock is None else self.lead_clock.now_ns()
        return Report(
            self.node.get_fully_qualified_name(),
            clock_ns,
            self._ready,
            leaving,
            min(dues) if dues else None,
            self.pending,
            dict(self.published),
            self._matched,
            dict(self.taken),
            self._heard,
            self.clock_acks,
        )

    def idle(self, leaving: bool = False) -> None:
        """The runner found nothing to run: publish the report if anything but the clock changed."""
        if self._ack_pub is None:
            return
        r = self.report(leaving)
        if leaving:  # what the reports cost (benchmarks/bench_lockstep_breakdown.py)
            causes = json.dumps(dict(self.triggers))
            self.node.get_logger().info(f"lockstep: reports by cause {causes}")
        key = (
            r.ready,
            r.leaving,
            r.next_due_ns,
            r.pending,
            tuple(sorted(r.published.items())),
            tuple(sorted(r.matched.items())),
            tuple(sorted(r.taken.items())),
            tuple(sorted(r.heard.items())),
            r.clock_ns if r.clock_acks else None,
        )
        if key == self._last:
            return  # only the clock moved, and the simulator does not wait for this node's clock
        self.triggers[self._cause(key)] += 1
        self._since.clear()
        self._last = key
        self._ack_pub.publish(to_msg(r))

    def _cause(self, key: tuple) -> str:
        """What changed since the last report: topics taken, else a timer ran, else the clock."""
        if self._since:
            return "+".join(sorted(self._since))
        if self._last is not None and key[2] != self._last[2]:
            return "timer"
        return "clock" if self._last is not None and key[8] != self._last[8] else "other"


class Group:
    """The participants of one process (several nodes composed: :mod:`hsa_common.compose`); each
    reports when the process runs out of work."""

    def __init__(self, participants: Sequence[Participant]) -> None:
        self.participants = tuple(participants)

    def idle(self, leaving: bool = False) -> None:
        """Every participant reports (see :meth:`Participant.idle`)."""
        for participant in self.participants:
            participant.idle(leaving)


def heard(node: Node) -> dict[str, int]:
    """Publishers matched per subscribed topic (the fewest of the node's subscriptions on it),
    /clock included."""
    return _fewest((sub.topic_name, sub.get_publisher_count) for sub in node.subscriptions)


def matched_of(node: Node) -> dict[str, int]:
    """Subscriptions matched per published topic (the fewest of the node's publishers on it), /clock
    included: a coordinator's own side of discovery."""
    return _fewest((pub.topic_name, pub.get_subscription_count) for pub in node.publishers)


def _fewest(ends: Any) -> dict[str, int]:
    """Per topic (barrier topics aside), the smallest match count of the (topic, count function)
    pairs."""
    counts: dict[str, int] = {}
    for topic, count in ends:
        if topic not in UNWATCHED:
            n = count()
            counts[topic] = min(n, counts.get(topic, n))
    return counts


def to_msg(r: Report) -> LockstepAck:
    """Report → LockstepAck."""
    msg = LockstepAck(
        node=r.node,
        ready=r.ready,
        leaving=r.leaving,
        clock_acks=r.clock_acks,
        next_due=-1 if r.next_due_ns is None else r.next_due_ns,
        pending=r.pending,
    )
    msg.clock = convert.stamp_msg(r.clock_ns)
    msg.pub_topics = list(r.published.keys() | r.matched.keys())
    msg.published = [r.published.get(t, 0) for t in msg.pub_topics]
    msg.matched = [r.matched.get(t, UNMATCHED) for t in msg.pub_topics]
    msg.sub_topics = list(r.taken)
    msg.taken = [r.taken[t] for t in msg.sub_topics]
    msg.heard_topics = list(r.heard)
    msg.heard = [r.heard[t] for t in msg.heard_topics]
    return msg


def from_msg(msg: LockstepAck) -> Report:
    """LockstepAck → Report."""
    return Report(
        msg.node,
        convert.stamp_ns(msg.clock),
        msg.ready,
        msg.leaving,
        None if msg.next_due < 0 else msg.next_due,
        msg.pending,
        dict(zip(msg.pub_topics, msg.published)),
        {t: n for t, n in zip(msg.pub_topics, msg.matched) if n != UNMATCHED},
        dict(zip(msg.sub_topics, msg.taken)),
        dict(zip(msg.heard_topics, msg.heard)),
        msg.clock_acks,
    )

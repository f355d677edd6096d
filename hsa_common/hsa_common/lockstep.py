"""A node's side of the lockstep barrier: count what it publishes and takes, and report when it runs
out of work.

``Participant(node)`` wraps the node's publishers, subscriptions, service servers and clients to
count messages per topic (services as ``srv:<name>``; /clock, /rosout, /parameter_events, the
barrier's own topic and the node's private parameter/lifecycle services are not counted), and its
timers and clock subscriptions to count the callbacks that can change its report (``activity``),
and publishes an ``hsa_msgs/LockstepAck`` on ``ACK_TOPIC`` when the runner finds no callback ready
(:func:`hsa_common.runner.spin_lockstep`, :class:`hsa_core.sim.lockstep.ReportPacing`), spinning
rclpy's events executor (or, with ``HSA_EXECUTOR=single``, a :class:`LockstepExecutor`). The
decisions are in :mod:`hsa_core.sim.lockstep`; the contract is in docs/simulation.md. A node may add
a readiness condition with a ``lockstep_ready() -> bool`` method (the recorder: every selected topic
subscribed). A node whose log times are simulated time (the recorder) logs through a
:class:`LeadClock` kept as its ``lockstep_clock``: the coordinator sends it each timer instant with
the counts that precede it, and the participant reports every move of that clock; a message the node
takes is logged once its instant is known (:class:`hsa_core.sim.lockstep.LogTimes`), whatever
arrived first, the message or the clock of its instant.
"""

from __future__ import annotations

import inspect
import json
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack
from typing import Any, Protocol

from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ConditionReachedException,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from hsa_common import convert
from hsa_core.sim.lockstep import LogTimes, Report
from hsa_msgs.msg import LockstepAck, LockstepLead

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
"""Hidden topic of the leads (``hsa_msgs/LockstepLead``): each timer instant, sent with /clock to
each node with a :class:`LeadClock`."""
LEAD_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=16,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
"""Reliable: the coordinator sends each lead once (one per recording node; an instant finishes only
once every one of them is there)."""
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
    """A node's log times in simulated time: :meth:`log` writes a message taken now at the clock of
    the instant it was published in (lockstep: :class:`hsa_core.sim.lockstep.LogTimes`, fed with
    the leads for this node; otherwise at once, at the node clock). ``taken`` is the node's
    participant's count per topic (set by :class:`Participant`), the counts the leads refer to."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.lead_ns = 0
        self.taken: Counter[str] | None = None
        self._times: LogTimes | None = None
        if enabled(node):
            self._times = LogTimes()
            node.create_subscription(LockstepLead, LEAD_TOPIC, self._lead, LEAD_QOS)

    def _lead(self, msg: LockstepLead) -> None:
        if msg.node != self.node.get_fully_qualified_name():
            return
        t_ns = convert.stamp_ns(msg.clock)
        assert self._times is not None
        self._times.lead(t_ns, dict(zip(msg.topics, msg.taken)))
        self.lead_ns = max(self.lead_ns, t_ns)

    def now_ns(self) -> int:
        """[ns] the later of the node clock and the latest lead instant."""
        return max(self.node.get_clock().now().nanoseconds, self.lead_ns)

    def log(self, topic: str, write: Callable[[int], None]) -> None:
        """Call ``write(t_ns)`` with the log time of the message of ``topic`` taken now: at once
        off lockstep, else once its instant is known."""
        if self._times is None or self.taken is None:
            write(self.now_ns())
            return
        self._times.take(topic, self.taken[topic], self.now_ns(), write)

    def flush(self) -> None:
        """Write what is held (the node is ending: no later instant comes)."""
        if self._times is not None:
            self._times.flush()


def publish_leads(publisher: Publisher, t_ns: int, leads: Mapping[str, Mapping[str, int]]) -> None:
    """A coordinator's leads of instant ``t_ns``: one per node of ``leads``
    (:meth:`hsa_core.sim.lockstep.Barrier.leads`), with the messages it took before the instant."""
    for node, taken in leads.items():
        publisher.publish(
            LockstepLead(
                clock=convert.stamp_msg(t_ns),
                node=node,
                topics=list(taken),
                taken=list(taken.values()),
            )
        )


WAITABLE_PERIOD = 0.02
"""[s] of wall time between two waits of a :class:`LockstepExecutor` that include waitables."""
RCLPY_INTERNALS = (
    "_context",
    "_is_shutdown",
    "_make_handler",
    "_sigint_gc",
    "_take_client",
    "_take_guard_condition",
    "_take_service",
    "_take_subscription",
    "_take_timer",
    "_take_waitable",
    "_tasks",
    "_tasks_lock",
)
"""The private parts of rclpy's Executor (Jazzy) that :class:`LockstepExecutor` builds on."""
Entities = tuple[tuple[Any, ...], ...]
"""Per node: its subscriptions, timers, clients, services, guard conditions and waitables."""


class LockstepExecutor(SingleThreadedExecutor):
    """rclpy's single-threaded executor for the lockstep spin, with a lean wait: the same callbacks
    run, one at a time in rclpy's order, but the wait set is built once per change of the nodes'
    entities (their handles held meanwhile) instead of once per wait, and the executor's own guard
    condition, which rclpy triggers after every callback, does not end a wait (a wait lasts at most
    the spin's period, and new entities or tasks are seen at the next one). A subscription's plain
    callback runs without rclpy's task around it (:class:`Take`). The waitables (the QoS
    event handlers of every publisher and subscription: incompatible QoS or type, which only log)
    join a wait at most every ``WAITABLE_PERIOD`` of wall time: they are most of a wait set's
    entities, and a wait's cost grows with them. Pending tasks (service futures' callbacks,
    coroutines), a waiting for chosen nodes and a wait without timeout take rclpy's own path."""

    def __init__(self) -> None:
        super().__init__()
        self.lean = all(hasattr(self, name) for name in RCLPY_INTERNALS) and hasattr(
            Subscription, "CallbackType"
        )
        """Whether this rclpy has the internals the lean wait uses (if not: rclpy's wait)."""
        self._entities: Entities | None = None
        self._held = ExitStack()
        self._wait_set: Any = None
        self._waitables_due = 0.0  # [s] monotonic time from which the waitables join a wait
        self._with_waitables = False  # whether the last wait had them

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """rclpy's shutdown, and the entities' handles are released (they can be destroyed)."""
        done = super().shutdown(timeout_sec)
        self._release()
        return done

    def _release(self) -> None:
        self._held.close()
        self._entities, self._wait_set = None, None

    def _prepare(self, nodes: Sequence[Node], now: float) -> Any:
        """The wait set of the nodes' entities now (the waitables if due at ``now``), rebuilt only
        when they changed."""
        entities = tuple(
            (
                tuple(n.subscriptions),
                tuple(n.timers),
                tuple(n.clients),
                tuple(n.services),
                tuple(n.guards),
                tuple(n.waitables),
            )
            for n in nodes
        )
        if entities != self._entities:
            self._release()
            counts = [0, 1, 0, 0, 0, 0]  # subscriptions, guards (the SIGINT one), timers, ...
            for subs, timers, clients, services, guards, waitables in entities:
                for i, group in ((0, subs), (1, guards), (2, timers), (3, clients), (4, services)):
                    for entity in group:
                        self._held.enter_context(entity.handle)
                        counts[i] += 1
                for waitable in waitables:
                    self._held.enter_context(waitable)
                    more = waitable.get_num_entities()
                    counts[0] += more.num_subscriptions
                    counts[1] += more.num_guard_conditions
                    counts[2] += more.num_timers
                    counts[3] += more.num_clients
                    counts[4] += more.num_services
                    counts[5] += more.num_events
            self._held.enter_context(self._sigint_gc.handle)
            with self._context.handle:
                self._wait_set = _rclpy.WaitSet(*counts, self._context.handle)
            self._entities = entities
        wait_set = self._wait_set
        wait_set.clear_entities()
        self._with_waitables = now >= self._waitables_due
        if self._with_waitables:
            self._waitables_due = now + WAITABLE_PERIOD
        for subs, timers, clients, services, guards, waitables in entities:
            for sub in subs:
                wait_set.add_subscription(sub.handle)
            for client in clients:
                wait_set.add_client(client.handle)
            for srv in services:
                wait_set.add_service(srv.handle)
            for tmr in timers:
                wait_set.add_timer(tmr.handle)
            for gc in guards:
                if gc._executor_triggered:  # triggered but not handled: as rclpy
                    gc.trigger()
                wait_set.add_guard_condition(gc.handle)
            if self._with_waitables:
                for waitable in waitables:
                    waitable.add_to_wait_set(wait_set)
        wait_set.add_guard_condition(self._sigint_gc.handle)
        return wait_set

    def _wait_for_ready_callbacks(
        self,
        timeout_sec: float | None = None,
        nodes: list[Node] | None = None,
        condition: Callable[[], bool] = lambda: False,
    ) -> Iterator[tuple[Any, Any, Node]]:
        """The ready callbacks of one wait of at most ``timeout_sec`` (see the class docstring)."""
        with self._tasks_lock:
            self._tasks = [t for t in self._tasks if not t[0].done() and not t[0].cancelled()]
            busy = bool(self._tasks)
        plain = not isinstance(timeout_sec, (int, float))
        if not self.lean or busy or nodes is not None or plain:
            yield from super()._wait_for_ready_callbacks(timeout_sec, nodes, condition)
            return
        deadline = time.monotonic() + max(timeout_sec, 0.0)
        while True:
            if self._is_shutdown:
                raise ShutdownException()
            if not self._context.ok():
                raise ExternalShutdownException()
            if condition():
                raise ConditionReachedException()
            nodes_now = self.get_nodes()
            try:
                wait_set = self._prepare(nodes_now, time.monotonic())
            except InvalidHandle:  # destroyed while held: rclpy's path sorts it out
                self._release()
                yield from super()._wait_for_ready_callbacks(timeout_sec, nodes, condition)
                return
            wait_set.wait(max(round((deadline - time.monotonic()) * 1e9), 0))
            if self._is_shutdown:
                raise ShutdownException()
            if not self._context.ok():
                raise ExternalShutdownException()
            yielded = False
            for handler in self._ready(wait_set, nodes_now):
                yielded = True
                yield handler
            if yielded:
                return
            if time.monotonic() >= deadline:
                raise TimeoutException()

    def _ready(self, wait_set: Any, nodes: Sequence[Node]) -> Iterator[tuple[Any, Any, Node]]:
        """Handlers of the entities ready in ``wait_set``, in rclpy's order."""
        subs = set(wait_set.get_ready_entities("subscription"))
        guards = set(wait_set.get_ready_entities("guard_condition"))
        timers = set(wait_set.get_ready_entities("timer"))
        clients = set(wait_set.get_ready_entities("client"))
        services = set(wait_set.get_ready_entities("service"))
        for node in nodes:
            for gc in node.guards:
                if gc.handle.pointer in guards:
                    gc._executor_triggered = True
        waited = (
            {id(w) for entities in self._entities or () for w in entities[5]}
            if self._with_waitables
            else set()
        )
        for node in nodes:
            for wt in node.waitables:
                if id(wt) in waited and wt.is_ready(wait_set) and self.can_execute(wt):
                    yield self._make_handler(wt, node, self._take_waitable), wt, node
        for node in nodes:
            for tmr in node.timers:
                if (
                    tmr.handle.pointer in timers
                    and tmr.handle.is_timer_ready()
                    and self.can_execute(tmr)
                ):
                    yield self._make_handler(tmr, node, self._take_timer), tmr, node
            for sub in node.subscriptions:
                if sub.handle.pointer in subs and self.can_execute(sub):
                    if inspect.iscoroutinefunction(sub.callback):
                        yield self._make_handler(sub, node, self._take_subscription), sub, node
                    else:
                        yield Take(sub), sub, node
            for gc in node.guards:
                if gc._executor_triggered and self.can_execute(gc):
                    yield self._make_handler(gc, node, self._take_guard_condition), gc, node
            for client in node.clients:
                if client.handle.pointer in clients and self.can_execute(client):
                    yield self._make_handler(client, node, self._take_client), client, node
            for srv in node.services:
                if srv.handle.pointer in services and self.can_execute(srv):
                    yield self._make_handler(srv, node, self._take_service), srv, node


class Take:
    """A ready subscription's handler: when called, takes its message and runs its plain callback,
    as rclpy's handler task does (a message already gone or a destroyed subscription: nothing);
    an exception of the callback is kept for :meth:`exception`, as a task keeps it."""

    __slots__ = ("_error", "_sub")

    def __init__(self, sub: Subscription) -> None:
        self._sub = sub
        self._error: Exception | None = None

    def __call__(self) -> None:
        sub = self._sub
        try:
            with sub.handle:
                info = sub.handle.take_message(sub.msg_type, sub.raw)
        except InvalidHandle:
            return
        if info is None:
            return
        args = (info[0],) if sub._callback_type is Subscription.CallbackType.MessageOnly else info
        try:
            sub.callback(*args)
        except Exception as exc:
            self._error = exc

    def exception(self) -> Exception | None:
        """The exception the callback raised, or None."""
        return self._error


class Reporter(Protocol):
    """What the runner's lockstep spin needs: a report whenever the process has run out of work."""

    @property
    def activity(self) -> int:
        """Callbacks run so far that can change a report (the events-executor spin's idle test)."""

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
        if self.lead_clock is not None:
            self.lead_clock.taken = self.taken  # the counts its leads refer to
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
        self.activity = 0  # callbacks run that can change the report (events-executor spin)
        self._seen = -1  # activity at the last report made with simulated time running
        self._timers: tuple = ()  # the node's timers at that report
        self._running = False  # the node clock has moved from 0 (readiness no longer matters)
        self.triggers: Counter[str] = Counter()  # reports per cause (topics taken, timer, clock)
        self.instrument()

    def instrument(self) -> None:
        """Wrap every publisher, subscription, service, client and timer not wrapped yet (nodes may
        create them later)."""
        for timer in self.node.timers:
            if id(timer) in self._wrapped or getattr(timer, "lockstep_wall", False):
                continue
            self._wrapped.add(id(timer))
            timer.callback = self._active(timer.callback)
        for pub in self.node.publishers:
            topic = pub.topic_name
            if id(pub) in self._wrapped or topic in UNCOUNTED:
                continue
            self._wrapped.add(id(pub))
            self._pubs.setdefault(topic, []).append(pub)
            self.published.setdefault(topic, 0)
            pub.publish = self._counting(pub.publish, self.published, topic)
        for sub in self.node.subscriptions:
            if id(sub) in self._wrapped:
                continue
            if sub.topic_name in UNCOUNTED:
                if sub.topic_name in ("/clock", LEAD_TOPIC):  # the clock moves: timers, clock_acks
                    self._wrapped.add(id(sub))
                    sub.callback = self._active(sub.callback)
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

    def _active(self, fn: Any) -> Any:
        def active(*args: Any, **kwargs: Any) -> Any:
            self.activity += 1
            return fn(*args, **kwargs)

        return active

    def _counting(
        self, fn: Any, counter: Counter[str], topic: str, since: set[str] | None = None
    ) -> Any:
        def counted(*args: Any, **kwargs: Any) -> Any:
            self.activity += 1
            counter[topic] += 1
            if since is not None:
                since.add(topic)
            return fn(*args, **kwargs)

        return counted

    def _calling(self, call_async: Any, topic: str) -> Any:
        def call(*args: Any, **kwargs: Any) -> Any:
            self.activity += 1
            self.published[topic] += 1
            self.pending += 1
            future = call_async(*args, **kwargs)
            future.add_done_callback(self._answered)
            return future

        return call

    def _answered(self, _future: Any) -> None:
        self.activity += 1
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
        self._running = now != 0
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
        timers = tuple(self.node.timers)
        if not leaving and self.activity == self._seen and timers == self._timers:
            return  # nothing ran since a report with simulated time running: the same report
        r = self.report(leaving)
        self._seen, self._timers = (self.activity if self._running else -1), timers
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

    @property
    def activity(self) -> int:
        """Callbacks run so far that can change a report (see :meth:`Participant.instrument`)."""
        return sum(p.activity for p in self.participants)

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

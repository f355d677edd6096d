"""bag_player: publish a bag into the live graph with the recorded timing.

``bag_player BAG [--topics T ...] [--remap FROM:=TO ...] [--rate R] [--start-offset S] [--loop [N]]
[--clock [HZ]] [--delay S] [--wait-for-subscribers [TIMEOUT]] [--wait-topics T ...] [--busy-wait-ms
MS] [--ros-args ...]``

* **Order and timing.** Messages are published in timestamp order across all files of the bag
  (:mod:`hsa_bag.bagio`), whatever the order of files and chunks. Message i of pass k is due at
  monotonic time ``t0 + (t_i + k·loop_span − t_first) / rate``, where ``t_first = bag start + start
  offset``; the player sleeps until ``busy_wait`` before that and busy-waits the rest (the OS wakes
  sleepers up to a scheduler tick late), and pacing uses ``time.monotonic`` only, so wall-clock
  jumps do not matter.
* **Loop.** ``--loop`` repeats forever, ``--loop N`` plays N passes. Pass k is shifted by
  ``k·loop_span`` with ``loop_span`` = played span + one mean message period, so playback time and
  /clock never go backwards. Message contents (header stamps included) are published as recorded.
* **/clock.** With ``--clock [HZ]`` (default 40 Hz, as ``ros2 bag play --clock``)
  rosgraph_msgs/Clock carries the playback time, first at the start time, then every 1/HZ s of wall
  time, reliable keep-last 1 (compatible with best-effort and reliable subscribers).
* **Topics.** ``--topics`` selects by recorded name; ``--remap FROM:=TO`` publishes FROM under TO.
  Messages go out as the recorded bytes; each type's class comes from ``importlib`` (``<pkg>.msg``)
  and the QoS from the offers stored in the bag (:func:`hsa_bag.qos.publisher_profile`).
* **Start.** ``--wait-for-subscribers`` first waits (bounded) for a subscriber on every played
  topic, or only on the recorded names given to ``--wait-topics`` (e.g. the inputs of the nodes
  under test, not topics only a recorder or viewer may take), and plays once each has stayed
  matched for ``MATCH_SETTLE`` s, so that the subscribers have matched the player too.
* **Lockstep** (ROS parameter ``lockstep: true``, with ``use_sim_time``; the replay graph's
  default): the player owns /clock and plays losslessly and deterministically, whatever the
  machine's load. It coordinates the barrier of :mod:`hsa_core.sim.lockstep` (decisions in
  :mod:`hsa_core.sim.playback`): simulated time starts once the nodes named in the parameter
  ``participants`` have reported and every topic the player publishes is matched by the participants
  that take it; each message is published at the instant of its log time (timer dues of the
  participants in between are instants of their own), after every message before it has been taken
  and the instant's timers have run. ``--rate``, ``--clock HZ`` and ``--busy-wait-ms`` do not apply.
  An instant not finished within ``barrier_timeout`` s of wall time (10× that for the start) is an
  ERROR naming what holds it, and the player exits 1.
* **Output.** Progress goes through the node's logger (stderr, which ``ros2 launch`` shows on the
  screen; stdout it sends to the log file only): ``ready`` once the publishers exist, then ``playing
  …`` and ``published …``. Refusals before the node exists (bag, arguments) are one line
  ``bag_player: …`` on stderr.
* **Exit code** 0 when done or stopped (SIGINT, SIGTERM, SIGHUP, SIGQUIT, or the end of the process
  that started it: :mod:`hsa_common.parent_death`), 1 after a lockstep barrier timeout or when its
  launcher had already ended, 2 for a bad bag, argument or parameter.
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock

from hsa_bag.bagio import Bag, BagError
from hsa_bag.msgtypes import message_class
from hsa_bag.play_options import Options, parse_args, split_ros_args
from hsa_bag.qos import publisher_profile
from hsa_common import convert, lockstep, parent_death, rosenv
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare
from hsa_core.sim.lockstep import Barrier
from hsa_core.sim.playback import Action, LockstepPlayback
from hsa_msgs.msg import LockstepAck, LockstepLead

CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
ACK_TIMEOUT = Duration(seconds=5.0)
MATCH_SETTLE = 0.5
"""[s] a subscription stays matched before --wait-for-subscribers lets the play start: our writer
matching it does not mean it matched our writer yet (its process learns of the writer by discovery
too, later under load, and a volatile reader drops what came before)"""
LOCKSTEP_SPIN = 0.01  # [s] longest wait for a participant's report while the barrier holds

SPECS = (
    ParamSpec(
        "participants",
        [""],
        "lockstep: fully qualified names of the nodes simulated time waits for before "
        "it starts (others join when they first report)",
        read_only=True,
    ),
    ParamSpec(
        "barrier_timeout",
        30.0,
        "lockstep: [s] of wall time an instant may take before the run fails (the start: 10x)",
        low=0.1,
        high=3600.0,
        read_only=True,
    ),
)
"""ROS parameters of the player (besides ``lockstep`` and ``use_sim_time``); the playback options
are arguments."""


@dataclass(frozen=True)
class Result:
    """What a play run did: messages published, passes completed, wall time and the worst lateness
    [s]."""

    published: int
    passes: int
    elapsed: float
    max_late: float
    failure: str = ""  # lockstep: why the barrier timed out


def message_classes(bag: Bag, options: Options) -> dict[str, type]:
    """The message class of every topic to play; BagError naming a topic not in the bag or a type
    not installed."""
    topics = list(options.topics) or sorted(bag.topics)
    for name in [*topics, *options.remap]:
        bag.topic(name)
    for name in options.wait_topics:
        if name not in topics:
            raise BagError(f"--wait-topics {name} is not a played topic")
    classes = {}
    for name in topics:
        msgtype = bag.topics[name].msgtype
        try:
            classes[name] = message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            raise BagError(f"type {msgtype} of topic {name} is not installed ({exc})") from exc
    return classes


class Player:
    """Publishes one bag through one node; :meth:`play` returns when done or when ``stop`` is
    set."""

    def __init__(
        self,
        bag: Bag,
        options: Options,
        classes: dict[str, type],
        node: Node,
        stop: parent_death.StopFlag,
        playback: LockstepPlayback | None = None,
    ) -> None:
        self.bag = bag
        self.node = node
        self.playback = playback
        self.options = options
        self.stop = stop
        self.topics = list(classes)
        self.publishers: dict[str, Publisher] = {
            name: node.create_publisher(
                cls, options.remap.get(name, name), self._profile(bag, name)
            )
            for name, cls in classes.items()
        }
        self.clock: Publisher | None = None
        if options.clock_hz > 0 or playback is not None:
            self.clock = node.create_publisher(Clock, "/clock", CLOCK_QOS)
        self.lead = (
            None
            if playback is None
            else node.create_publisher(LockstepLead, lockstep.LEAD_TOPIC, lockstep.LEAD_QOS)
        )
        self.first = bag.start + round(options.start_offset * 1e9)  # bag time [ns] played at t0
        mean_period = (bag.end - bag.start) // max(bag.message_count - 1, 1)
        self.loop_span = max(bag.end - self.first, 0) + mean_period
        self._t0 = 0.0
        self._next_clock = 0.0

    def _profile(self, bag: Bag, topic: str) -> QoSProfile:
        """The recorded offers' profile; reliable in lockstep: a subscription matched just before
        time starts (a recorder that subscribes on discovery) may not know the player yet, and only
        a reliable writer resends."""
        profile = publisher_profile(bag.topics[topic].qos)
        if self.playback is not None:
            profile.reliability = ReliabilityPolicy.RELIABLE
        return profile

    def _playback_ns(self, when: float) -> int:
        """Playback (bag) time [ns] at monotonic time ``when``."""
        return self.first + round((when - self._t0) * self.options.rate * 1e9)

    def _wait(self, target: float) -> bool:
        """Sleep until ``busy_wait`` before monotonic time ``target``, then busy-wait; False if
        stopped."""
        remaining = target - time.monotonic() - self.options.busy_wait
        if remaining > 0 and self.stop.wait(remaining):
            return False
        while time.monotonic() < target:
            pass
        return not self.stop.is_set()

    def _publish_clock(self, when: float) -> None:
        """Publish the playback time of monotonic time ``when`` on /clock."""
        assert self.clock is not None
        self.clock.publish(convert.clock_msg(self._playback_ns(when)))

    def _sleep_until(self, due: float) -> bool:
        """Wait for ``due``, publishing the /clock ticks that fall before it; False if stopped."""
        while self.clock is not None and self._next_clock <= due:
            if not self._wait(self._next_clock):
                return False
            self._publish_clock(self._next_clock)
            self._next_clock += 1.0 / self.options.clock_hz
        return self._wait(due)

    def _wait_for_subscribers(self) -> None:
        """Wait (bounded) until every awaited topic has had a matched subscription for MATCH_SETTLE
        s; report the ones that have none."""
        awaited = {
            n: p
            for n, p in self.publishers.items()
            if not self.options.wait_topics or n in self.options.wait_topics
        }
        deadline = time.monotonic() + self.options.wait_for_subscribers
        matched_since: float | None = None
        while time.monotonic() < deadline and not self.stop.is_set():
            if not all(p.get_subscription_count() > 0 for p in awaited.values()):
                matched_since = None
            elif matched_since is None:
                matched_since = time.monotonic()
            elif time.monotonic() - matched_since >= MATCH_SETTLE:
                return
            self.stop.wait(0.05)
        missing = [n for n, p in awaited.items() if p.get_subscription_count() == 0]
        if missing:
            self.node.get_logger().warning(
                f"no subscriber for {', '.join(missing)}; playing anyway"
            )

    def play(self) -> Result:
        """Publish the selected messages, pass after pass; return counts and timing."""
        if self.options.wait_for_subscribers > 0:
            self._wait_for_subscribers()
        if self.options.delay > 0 and self.stop.wait(self.options.delay):
            return Result(0, 0, 0.0, 0.0)
        if self.playback is not None:
            return self._play_lockstep(self.playback)
        published = passes = 0
        max_late = 0.0
        self._t0 = self._next_clock = time.monotonic()
        scale = 1e-9 / self.options.rate
        while not self.stop.is_set() and (self.options.loops == 0 or passes < self.options.loops):
            offset = passes * self.loop_span - self.first
            before = published
            for topic, stamp, data in self.bag.messages(self.topics, start=self.first):
                due = self._t0 + (stamp + offset) * scale
                if not self._sleep_until(due):
                    break
                self.publishers[topic].publish(data)
                max_late = max(max_late, time.monotonic() - due)
                published += 1
            else:
                passes += 1
            if published == before:
                break  # nothing after the start offset: another pass would spin
        elapsed = time.monotonic() - self._t0
        self._wait_for_acks()
        return Result(published, passes, elapsed, max_late)

    def _wait_for_acks(self) -> None:
        """Wait (bounded) until reliable subscribers have acknowledged every message (the last
        /clock too)."""
        for pub in [*self.publishers.values(), *([self.clock] if self.clock is not None else [])]:
            if pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE:
                pub.wait_for_all_acked(ACK_TIMEOUT)

    def _timeline(self, passes: list[int]) -> Iterator[tuple[str, int, bytes]]:
        """(topic, playback time [ns], data) of every message to play, pass after pass; counts
        passes in ``passes``."""
        while self.options.loops == 0 or passes[0] < self.options.loops:
            shift = passes[0] * self.loop_span
            played = False
            for topic, stamp, data in self.bag.messages(self.topics, start=self.first):
                played = True
                yield topic, stamp + shift, data
            passes[0] += 1
            if not played:
                return  # nothing after the start offset: another pass would spin

    def _play_lockstep(self, playback: LockstepPlayback) -> Result:
        """Lockstep: publish each message at the instant of its log time, as the barrier allows
        (module docstring)."""
        assert self.clock is not None
        executor = SingleThreadedExecutor()
        executor.add_node(self.node)
        passes = [0]
        timeline = self._timeline(passes)
        upcoming = next(timeline, None)
        published = 0
        failure = ""
        start = time.monotonic()
        logger = self.node.get_logger()
        while not self.stop.is_set():
            started = playback.barrier.started
            # graph queries only before the start
            matched = lockstep.matched_of(self.node) if not started else {}
            step = playback.step(
                None if upcoming is None else upcoming[1], matched, time.monotonic()
            )
            if playback.barrier.started and not started:
                logger.info(
                    f"lockstep: simulated time starts ({len(playback.barrier.reports)} "
                    "participants)"
                )
            if step.action is Action.PUBLISH:
                assert upcoming is not None
                self.publishers[upcoming[0]].publish(upcoming[2])
                published += 1
                upcoming = next(timeline, None)
            elif step.action is Action.LEAD:
                assert self.lead is not None and step.t_ns is not None
                lockstep.publish_leads(self.lead, step.t_ns, playback.barrier.leads())
            elif step.action is Action.CLOCK:
                assert self.clock is not None and step.t_ns is not None
                self.clock.publish(convert.clock_msg(step.t_ns))
            elif step.action is Action.DONE:
                break
            elif step.action is Action.FAIL:
                failure = step.reason
                logger.error(failure)
                break
            else:
                if not playback.barrier.started:
                    logger.info(
                        f"lockstep: simulated time has not started: {step.reason}",
                        throttle_duration_sec=5.0,
                    )
                executor.spin_once(timeout_sec=LOCKSTEP_SPIN)
        executor.remove_node(self.node)
        executor.shutdown(timeout_sec=1.0)
        if not failure:
            self._wait_for_acks()
        return Result(published, passes[0], time.monotonic() - start, 0.0, failure)


def main(argv: list[str] | None = None) -> int:
    """Console script ``bag_player``."""
    ours, ros_args = split_ros_args(sys.argv[1:] if argv is None else argv)
    path, options = parse_args(ours)
    try:
        bag = Bag(path)
    except BagError as exc:
        print(f"bag_player: {exc}", file=sys.stderr)
        return 2
    try:
        classes = message_classes(bag, options)
    except BagError as exc:
        bag.close()
        print(f"bag_player: {exc}", file=sys.stderr)
        return 2
    rosenv.ensure_for_node()  # after the argument and bag checks: a refusal stays one line
    if (
        parent_death.tie_to_parent(signal.SIGTERM) is parent_death.Tie.ORPHANED
    ):  # before the SIGHUP handler (nohup)
        print(
            "bag_player: not starting: the launcher that started it has already ended",
            file=sys.stderr,
        )
        return 1
    stop = parent_death.StopFlag()
    rclpy.init(args=["bag_player", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    # as every node: a closed terminal or Ctrl-\ stops it
    parent_death.on_stop_signals(lambda signum, _frame: stop.set(signum))
    node = rclpy.create_node("bag_player")
    try:
        try:
            params = declare(node, SPECS)
        except ParameterValidationError as exc:
            node.get_logger().fatal(f"refusing to start: {exc}")
            return 2
        playback = None
        if lockstep.enabled(node):
            barrier = Barrier(n for n in params["participants"] if n)
            playback = LockstepPlayback(barrier, params["barrier_timeout"])
        player = Player(bag, options, classes, node, stop, playback)
        if playback is not None:
            barrier.own = lockstep.Participant(
                node, publish_acks=False
            ).published  # live: its messages count at once
            node.create_subscription(
                LockstepAck,
                lockstep.ACK_TOPIC,
                lambda m: barrier.report(lockstep.from_msg(m)),
                lockstep.ACK_READER_QOS,
            )
        span = (bag.end - player.first) / 1e9
        topics = ", ".join(player.topics)
        pace = (
            f"in lockstep with {list(barrier.expected)}"
            if playback is not None
            else f"at rate {options.rate}"
        )
        logger = node.get_logger()
        # publishers and lockstep subscriptions exist, as every node's runner logs it
        logger.info("ready")
        logger.info(f"playing {path}: {topics}; {span:.3f} s of bag time {pace}")
        result = player.play()
        summary = (
            "lockstep"
            if playback is not None
            else f"latest {result.max_late * 1e3:.2f} ms behind schedule"
        )
        logger.info(
            f"published {result.published} messages in {result.passes} pass(es), "
            f"{result.elapsed:.3f} s; {summary}"
        )
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        bag.close()
    return 1 if result.failure else 0

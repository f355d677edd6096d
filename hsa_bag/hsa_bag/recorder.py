"""bag_recorder: record topics of the live graph into a rosbag2 MCAP bag (rosbags Writer, metadata
version 9).

Every selected topic is subscribed with ``raw=True`` as soon as it has a publisher, and the
serialized bytes go straight into the bag. The graph is searched again every ``discovery_period`` so
late publishers are caught. The subscription QoS is adapted to the publishers' offers and the offers
are stored in the bag (see :mod:`hsa_bag.qos`); a publisher that appears later with a weaker offer
(best effort, volatile) gets the topic re-subscribed so it is not silently missed (discovery runs on
the steady clock, also under simulated time). /clock is not recorded by default. In a lockstep graph
the recorder is a barrier participant: with a ``topics`` list, simulated time does not start before
every listed topic is subscribed, and the barrier then guarantees that every message published on
them is in the bag. Types come from the Jazzy typestore and from the ``.msg`` files that interface
packages install (:mod:`hsa_bag.msgtypes`); a topic whose type is unknown is reported and skipped.

**Only what decodes is recorded.** Raw bytes are not decoded by the middleware, so malformed CDR
(truncated, garbage, a string that is not UTF-8) would reach the bag and break its readers. Each
message is decoded with the very definition written into the bag (the rosbags typestore) before it
is written; one that does not decode is left out and counted per topic: on /diagnostics
(``undecodable <topic>``, WARN), in a WARN line at most every ``UNDECODABLE_LOG_PERIOD``, in the
final summary line and in the bag's ``custom_data`` (``hsa_bag.undecodable``).

**Timestamps** are receive times: the node clock (ROS time, i.e. system time, or /clock with
``use_sim_time``) read in the subscription callback, in ns; in lockstep the instant the message
was published in (:class:`hsa_common.lockstep.LeadClock`: a timer's messages can arrive before
/clock, so a message is written once the next lead says which instant it belongs to). Header stamps
inside the messages are untouched.

Files, splitting and crash safety: :mod:`hsa_bag.storage`. The pending chunk is flushed at
``chunk_size`` bytes and every ``flush_period`` s, so a SIGKILL loses at most the last
``flush_period`` (``bag_recover`` then completes the unfinished split). SIGINT/SIGTERM close the bag
cleanly (runner ``on_shutdown`` hook). The bag directory is logged at start and at the end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import rclpy.logging
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSCompatibility, QoSProfile, qos_check_compatible
from rclpy.subscription import Subscription
from rclpy.topic_endpoint_info import TopicEndpointInfo
from rosbags.serde import SerdeError

from hsa_bag.msgtypes import TypeRegistry, UnknownTypeError, message_class
from hsa_bag.qos import subscription_profile, to_bag
from hsa_bag.storage import MAX_CHUNK_SIZE, SplitBagWriter
from hsa_common import lockstep, runner
from hsa_common.diagnostics import OK, WARN, Diagnostics, Report
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates

EXCLUDED = frozenset({"/rosout", "/parameter_events", "/clock"})
UNDECODABLE_LOG_PERIOD = 5.0  # [s] steady time between two WARN lines about undecodable messages
UNDECODABLE_KEY = (
    "hsa_bag.undecodable"  # custom_data key: "<topic>: <count>, ..." of the messages left out
)

SPECS = (
    ParamSpec(
        "topics",
        Parameter.Type.STRING_ARRAY,
        "topics to record (relative names resolve in the node namespace); unset or empty = every "
        "topic on the graph except /rosout, /parameter_events and hidden topics",
        read_only=True,
    ),
    ParamSpec(
        "output",
        "",
        "bag directory to create (an existing one is refused); ending in '/': a new "
        "<YYYYmmdd-HHMMSS> directory inside it (_2, _3, ... if taken), so every start gets its own "
        "bag; empty = out/bags/ (relative to the working directory)",
        read_only=True,
    ),
    ParamSpec(
        "max_bag_size",
        0,
        "[bytes] start a new split before a file would exceed this; 0 = never",
        low=0,
        high=2**62,
        read_only=True,
    ),
    ParamSpec(
        "max_bag_duration",
        0.0,
        "[s] start a new split after this much receive time; 0 = never",
        low=0.0,
        high=1e9,
        read_only=True,
    ),
    ParamSpec(
        "chunk_size",
        64 * 1024,
        "[bytes] MCAP chunk size; a full chunk is written and flushed at once",
        low=1024,
        high=MAX_CHUNK_SIZE,
        read_only=True,
    ),
    ParamSpec(
        "flush_period",
        1.0,
        "[s] flush the pending chunk this often (bounds what a killed recorder loses)",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
    ParamSpec(
        "discovery_period",
        1.0,
        "[s] search the graph for new topics and publishers this often",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
)


DEFAULT_OUTPUT = "out/bags/"


def output_path(output: str, stamp: str | None = None) -> Path:
    """The bag directory that parameter ``output`` names: the path itself; for a value ending in '/'
    (or empty: ``DEFAULT_OUTPUT``) a directory ``<stamp>`` inside it (default: the local date-time),
    or ``<stamp>_2``, ... if that is taken."""
    if output and not output.endswith("/"):
        return Path(output)
    parent = Path(output or DEFAULT_OUTPUT)
    stamp = stamp or time.strftime("%Y%m%d-%H%M%S")
    path, k = parent / stamp, 2
    while path.exists():
        path, k = parent / f"{stamp}_{k}", k + 1
    return path


def is_hidden(topic: str) -> bool:
    """Hidden topics have a name token starting with an underscore (e.g. action internals), as in
    rosbag2."""
    return any(token.startswith("_") for token in topic.split("/"))


@dataclass
class Recording:
    """A topic being recorded: bag handle, message class, subscription and the publishers (gids) its
    QoS suits."""

    handle: int
    msgtype: str
    message_class: type
    profile: QoSProfile
    subscription: Subscription
    publishers: frozenset[bytes]


def describe(profile: QoSProfile) -> str:
    """'reliable, transient_local' style summary of a subscription profile."""
    return f"{profile.reliability.name.lower()}, {profile.durability.name.lower()}"


class BagRecorder(Node):
    """Records the selected topics into one bag directory; see the module docstring."""

    def __init__(self) -> None:
        super().__init__("bag_recorder")
        params = declare(self, SPECS)
        guard_updates(self, SPECS)
        self._wanted = {self.resolve_topic_name(t) for t in params["topics"] or [] if t}
        self._types = TypeRegistry()
        self._bag = SplitBagWriter(
            output_path(params["output"]),
            self._types.store,
            max_bytes=params["max_bag_size"],
            max_duration=round(params["max_bag_duration"] * 1e9),
            chunk_size=params["chunk_size"],
            custom_data={"hsa_bag.timestamps": "receive time, node clock [ns]"},
        )
        try:
            self._bag.open()
        except FileExistsError as exc:
            raise ParameterValidationError(
                f"parameter 'output': {self._bag.path} exists already; refusing to overwrite it (a "
                f"new path, or '{self._bag.path}/' for a new date-time bag inside it)"
            ) from exc
        # log times; lockstep instants wait until it is there
        self.lockstep_clock = lockstep.LeadClock(self)
        self._recording: dict[str, Recording] = {}
        self._skipped: dict[str, str] = {}  # topic -> why it is not recorded (reported once)
        self._undecodable: dict[
            str, int
        ] = {}  # topic -> messages left out because they do not decode
        # steady time [s] of the last WARN about them
        self._undecodable_logged = -UNDECODABLE_LOG_PERIOD
        # discovery is a wall-clock matter
        lockstep.wall_timer(self, params["discovery_period"], self._discover)
        self.create_timer(params["flush_period"], self._bag.flush)
        Diagnostics(self).add("recording", self._report)
        self.get_logger().info(f"recording to {self._bag.path.resolve()}")
        self._discover()

    def lockstep_ready(self) -> bool:
        """Lockstep: simulated time may start once every listed topic is subscribed (nothing
        published is lost)."""
        if self.get_clock().now().nanoseconds > 0:
            return True  # time has started: readiness no longer matters
        self._discover()
        return self._wanted <= self._recording.keys()

    def _selected(self, topic: str) -> bool:
        """Whether ``topic`` is to be recorded."""
        if self._wanted:
            return topic in self._wanted
        return topic not in EXCLUDED and not is_hidden(topic)

    def _discover(self) -> None:
        """Subscribe to selected topics that have publishers now; re-adapt QoS where publishers
        changed."""
        for topic, types in self.get_topic_names_and_types():
            if not self._selected(topic) or topic in self._skipped:
                continue
            offers = self.get_publishers_info_by_topic(topic)
            if not offers:
                continue  # nothing offers QoS yet: wait for a publisher
            if topic in self._recording:
                self._adapt(topic, offers)
            else:
                self._start(topic, types, offers)

    def _skip(self, topic: str, reason: str) -> None:
        """Leave ``topic`` out of the bag and say why, once."""
        self._skipped[topic] = reason
        self.get_logger().warning(f"not recording {topic}: {reason}")

    def _start(self, topic: str, types: list[str], offers: list[TopicEndpointInfo]) -> None:
        """Register ``topic`` in the bag and subscribe to it."""
        if len(types) != 1:
            self._skip(topic, f"it has {len(types)} types ({', '.join(types)})")
            return
        msgtype = types[0]
        try:
            self._types.ensure(msgtype)
            cls = message_class(msgtype)
        except (UnknownTypeError, ImportError, AttributeError, ValueError) as exc:
            self._skip(topic, f"type {msgtype} is unavailable ({exc})")
            return
        profiles = [o.qos_profile for o in offers]
        handle = self._bag.add_topic(topic, msgtype, [to_bag(p) for p in profiles])
        profile = subscription_profile(profiles)
        sub = self.create_subscription(cls, topic, partial(self._write, topic), profile, raw=True)
        self._recording[topic] = Recording(
            handle, msgtype, cls, profile, sub, frozenset(bytes(o.endpoint_gid) for o in offers)
        )
        self.get_logger().info(
            f"recording {topic} [{msgtype}] ({describe(profile)}; {len(offers)} publisher(s))"
        )

    def _adapt(self, topic: str, offers: list[TopicEndpointInfo]) -> None:
        """Store the current offers for the next split; re-subscribe if a publisher cannot reach the
        subscription."""
        rec = self._recording[topic]
        publishers = frozenset(bytes(o.endpoint_gid) for o in offers)
        if publishers == rec.publishers:
            return
        rec.publishers = publishers
        profiles = [o.qos_profile for o in offers]
        self._bag.set_qos(rec.handle, [to_bag(p) for p in profiles])
        if all(qos_check_compatible(p, rec.profile)[0] != QoSCompatibility.ERROR for p in profiles):
            return
        self.destroy_subscription(rec.subscription)
        rec.profile = subscription_profile(profiles)
        rec.subscription = self.create_subscription(
            rec.message_class, topic, partial(self._write, topic), rec.profile, raw=True
        )
        self.get_logger().warning(
            f"re-subscribed {topic} ({describe(rec.profile)}): a new publisher offers less"
        )

    def _write(self, topic: str, data: bytes) -> None:
        """Subscription callback: the serialized message goes into the bag, stamped with the receive
        time, if it decodes with the bag's definition; otherwise it is counted (see the module
        docstring)."""
        rec = self._recording[topic]
        try:
            self._types.store.deserialize_cdr(data, rec.msgtype)
        except SerdeError as exc:
            self._left_out(topic, exc)
            return
        self.lockstep_clock.log(topic, partial(self._bag.write, rec.handle, data=data))

    def _left_out(self, topic: str, exc: SerdeError) -> None:
        """Count an undecodable message of ``topic``, note the counts in the bag and warn
        (throttled)."""
        self._undecodable[topic] = self._undecodable.get(topic, 0) + 1
        self._bag.set_custom_data(UNDECODABLE_KEY, self._undecodable_summary())
        now = time.monotonic()
        if now - self._undecodable_logged >= UNDECODABLE_LOG_PERIOD:
            self._undecodable_logged = now
            self.get_logger().warning(
                f"not recording undecodable messages ({self._undecodable_summary()} so far); last "
                f"on {topic}: {exc}"
            )

    def _undecodable_summary(self) -> str:
        """'<topic>: <count>, ...' of the messages left out because they do not decode."""
        return ", ".join(f"{topic}: {count}" for topic, count in sorted(self._undecodable.items()))

    def _report(self) -> Report:
        """Diagnostics: bag, file, counts; WARN while some topic cannot be recorded."""
        files = self._bag.files
        values = {
            "bag": str(self._bag.path.resolve()),
            "file": files[-1].name if files else "",
            "splits": len(files),
            "messages": self._bag.message_count,
            "topics": len(self._recording),
        }
        values.update({f"undecodable {t}": n for t, n in sorted(self._undecodable.items())})
        problems = []
        if self._skipped:
            values.update({f"skipped {t}": why for t, why in self._skipped.items()})
            problems.append(f"{len(self._skipped)} topic(s) not recorded")
        if self._undecodable:
            problems.append(f"{sum(self._undecodable.values())} undecodable message(s) left out")
        return (
            Report(WARN, "; ".join(problems), values)
            if problems
            else Report(OK, "recording", values)
        )

    def on_shutdown(self) -> None:
        """Write what waits for its log time, close the bag (summary, footer, final metadata.yaml)
        and say where it is."""
        self.lockstep_clock.flush()
        self._bag.close()
        files = ", ".join(p.name for p in self._bag.files) if self._bag.info else "no file"
        left_out = (
            f"; left out undecodable messages: {self._undecodable_summary()}"
            if self._undecodable
            else ""
        )
        rclpy.logging.get_logger(
            "hsa_bag.recorder"
        ).info(  # not the node logger: its /rosout publisher is gone
            f"wrote {self._bag.message_count} messages on {len(self._recording)} topic(s) to "
            f"{self._bag.path.resolve()} ({files}){left_out}"
        )


def main() -> None:
    """Console script ``bag_recorder``."""
    raise SystemExit(runner.run(BagRecorder, "bag_recorder"))

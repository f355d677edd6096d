"""QoS for recording and replay: what to subscribe with, what to store in the bag, what to publish
with.

* **Record** (as rosbag2 adapts its requests to the offers): reliable only if every publisher offers
  reliable, else best effort (a reliable subscription to a best-effort publisher delivers nothing,
  ecosystem.md §2 item 9); transient local only if every publisher offers it (so the latched sample
  of a late-recorded topic arrives); keep last ``RECORD_DEPTH``: 5 s of a 200 Hz stream, so a
  recorder stalled by a loaded machine catches up.
* **Store**: the profiles the publishers offered, as the graph reports them (DDS does not report
  history and depth: they are stored as ``unknown``/0, as rosbag2 stores them).
* **Replay**: reliable/transient local only if every recorded offer was; depth the recorded one if
  known, else 1 for transient local (a late joiner gets the latest sample, as with
  ``hsa_common.qos.LATCHED``) and 10 otherwise. Deadline, lifespan and liveliness are left at their
  defaults.
"""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

RECORD_DEPTH = 1000
REPLAY_DEPTH = 10


def _bag_time(duration: Duration) -> QosTime:
    """rclpy Duration → rosbags (sec, nsec); the infinite duration becomes rmw's {9223372036,
    854775807}."""
    sec, nsec = divmod(duration.nanoseconds, 1_000_000_000)
    return QosTime(sec, nsec)


def to_bag(profile: QoSProfile) -> Qos:
    """An offered rclpy QoS profile as rosbags stores it (the enum values are rmw's in both
    libraries)."""
    return Qos(
        history=QosHistory(int(profile.history)),
        depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_bag_time(profile.deadline),
        lifespan=_bag_time(profile.lifespan),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_bag_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def subscription_profile(offers: Sequence[QoSProfile]) -> QoSProfile:
    """The recording subscription that every offered publisher profile is compatible with."""
    reliable = bool(offers) and all(p.reliability == ReliabilityPolicy.RELIABLE for p in offers)
    latched = bool(offers) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=RECORD_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        liveliness=LivelinessPolicy.AUTOMATIC,
    )


def publisher_profile(offers: Sequence[Qos]) -> QoSProfile:
    """The replay publisher profile for the offers recorded in a bag (rclpy's default if none were
    recorded)."""
    if not offers:
        return QoSProfile(depth=REPLAY_DEPTH)
    reliable = all(q.reliability == QosReliability.RELIABLE for q in offers)
    latched = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offers)
    known_depths = [q.depth for q in offers if q.history == QosHistory.KEEP_LAST and q.depth > 0]
    depth = max(known_depths) if known_depths else (1 if latched else REPLAY_DEPTH)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )

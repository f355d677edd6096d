"""Recorded experiments for identification and verification: bags (or NPZ files) →
hsa_core.sysid.identification.Record.

From a bag: the EE pose stream (`<ns>/ee_pose`, hsa_msgs/PlanarPoseStamped, else `<ns>/state`,
hsa_msgs/PlanarState; found by type, in any namespace) with its mocap stamps, and the present twist
of the motors (`<ns>/phi_present`, the driver's reading) held (zero-order) onto those stamps, which
is what identification.md §6 replays. Times are seconds from the first pose. From an NPZ file:
arrays `t` (N,), `chiee` (N, 3), `phi` (N, 2) and optionally `payload` (N,) [kg]. The payload of a
record is a constant mass or a schedule [[t, mass], ...] (t from the record start, mass from then
on).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hsa_bag.bagio import Bag, BagError, stamp_ns
from hsa_core.sysid.excitation import zero_order_hold
from hsa_core.sysid.identification import Record

POSE_TYPES = {"hsa_msgs/msg/PlanarPoseStamped": "pose", "hsa_msgs/msg/PlanarState": "chiee"}
ACTUATION = "hsa_msgs/msg/PlanarActuation"


def _find_topic(bag: Bag, types: tuple[str, ...], suffix: str) -> str:
    """The topic of the first of `types` (in that order of preference) whose name ends with
    `suffix`."""
    for msgtype in types:
        names = sorted(
            n for n, info in bag.topics.items() if info.msgtype == msgtype and n.endswith(suffix)
        )
        if names:
            return names[0]
    raise BagError(
        f"{bag.path}: no topic '*{suffix}' of type {' or '.join(types)} (topics: "
        f"{', '.join(sorted(bag.topics))})"
    )


def read_bag(
    path: Path | str, pose_topic: str | None = None, phi_topic: str | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, chiee, phi) of a bag: poses at their stamps (sorted, duplicates dropped) and phi held
    onto them."""
    with Bag(path) as bag:
        if pose_topic is None:
            try:
                pose_topic = _find_topic(bag, ("hsa_msgs/msg/PlanarPoseStamped",), "ee_pose")
            except BagError:
                pose_topic = _find_topic(bag, ("hsa_msgs/msg/PlanarState",), "state")
        phi_topic = phi_topic or _find_topic(bag, (ACTUATION,), "phi_present")
        info = bag.topic(pose_topic)
        if info.msgtype not in POSE_TYPES:
            raise BagError(
                f"{bag.path}: topic {pose_topic} has type {info.msgtype}, expected one of "
                f"{list(POSE_TYPES)}"
            )
        if bag.topic(phi_topic).msgtype != ACTUATION:
            raise BagError(f"{bag.path}: topic {phi_topic} is not {ACTUATION}")
        stores = {pose_topic: bag.typestore(pose_topic), phi_topic: bag.typestore(phi_topic)}
        types = {pose_topic: info.msgtype, phi_topic: ACTUATION}
        poses: dict[int, tuple[float, float, float]] = {}
        phis: list[tuple[int, np.ndarray]] = []
        for topic, _, raw in bag.messages([pose_topic, phi_topic]):
            msg = stores[topic].deserialize_cdr(raw, types[topic])
            if topic == phi_topic:
                phis.append((stamp_ns(msg.header.stamp), np.asarray(msg.phi, dtype=float)))
            else:
                pose = getattr(msg, POSE_TYPES[info.msgtype])
                poses.setdefault(stamp_ns(msg.header.stamp), (pose.x, pose.y, pose.theta))
    if len(poses) < 3 or not phis:
        raise BagError(
            f"{path}: {len(poses)} poses on {pose_topic} and {len(phis)} on {phi_topic}; need >= 3 "
            "and >= 1"
        )
    stamps = sorted(poses)
    chiee = np.array([poses[s] for s in stamps])
    t = np.array([s - stamps[0] for s in stamps]) * 1e-9
    phis.sort(key=lambda item: item[0])
    phi = zero_order_hold([(p[0] - stamps[0]) * 1e-9 for p in phis], [p[1] for p in phis], t)
    return t, chiee, phi


def payload_series(t: np.ndarray, payload: float | Sequence[Sequence[float]]) -> np.ndarray:
    """Payload mass [kg] at every time t: a constant, or a schedule [[t_start, mass], ...] held from
    t_start on."""
    if isinstance(payload, (int, float)):
        return np.full(len(t), float(payload))
    schedule = np.asarray(payload, dtype=float)
    if schedule.ndim != 2 or schedule.shape[1] != 2 or np.any(np.diff(schedule[:, 0]) <= 0.0):
        raise ValueError(
            f"payload schedule must be [[t, mass], ...] with increasing t, got {payload!r}"
        )
    return zero_order_hold(schedule[:, 0], schedule[:, 1:], t)[:, 0]


def load_arrays(path: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(t, chiee, phi, payload or None) of a bag directory, an .mcap file or an .npz file."""
    path = Path(path)
    if path.suffix == ".npz":
        with np.load(path) as data:
            missing = [k for k in ("t", "chiee", "phi") if k not in data.files]
            if missing:
                raise BagError(f"{path}: arrays {missing} missing (need t, chiee, phi)")
            payload = data["payload"] if "payload" in data.files else None
            return data["t"] - data["t"][0], data["chiee"], data["phi"], payload
    return (*read_bag(path), None)


def load_record(
    path: Path | str,
    role: str,
    payload: float | Sequence[Sequence[float]] | None = None,
    name: str | None = None,
) -> Record:
    """A Record for identification (payload: given here, else the NPZ's array, else 0)."""
    t, chiee, phi, stored = load_arrays(path)
    if payload is not None:
        masses = payload_series(t, payload)
    else:
        masses = stored if stored is not None else np.zeros(len(t))
    return Record(name or Path(path).stem, t, chiee, phi, masses, role)


def save_npz(
    path: Path | str,
    t: np.ndarray,
    chiee: np.ndarray,
    phi: np.ndarray,
    payload: np.ndarray | None = None,
) -> Path:
    """Write a record in the NPZ layout load_arrays reads."""
    arrays = {
        "t": t,
        "chiee": chiee,
        "phi": phi,
        **({"payload": payload} if payload is not None else {}),
    }
    np.savez(path, **arrays)
    return Path(path)

"""mocap_bridge as a real process: 200 Hz mocap poses → exact planar poses, drops counted per
reason, parameters; the measured base pose checked like the platform pose and never used stale
(issue 22)."""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time import Time

from hsa_common import qos
from hsa_core.sensing import mocap
from hsa_msgs.msg import PlanarPoseStamped
from tests.ros.conftest import (
    ParameterClient,
    assert_refused_at_start,
    start_node,
    stop_process,
    wait_for_line,
    wait_until,
)

pytestmark = pytest.mark.ros

PERIOD_NS = 5_000_000  # 200 Hz
BASE = (0.3, 1.1, -0.4)  # [m] configured world position of the base markers of the shared bridge
COMMON = (
    # no queue drops on a busy machine
    "qos_overrides./mocap/platform/pose.subscription.depth:=100",
    "diagnostics_period:=0.2",
)
RECEIVE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
STATUS = "mocap_bridge: platform"
TILTED_TOPICS = (
    "platform_topic:=/tilted/platform/pose",
    "base_topic:=/tilted/base/pose",
    "qos_overrides./tilted/platform/pose.subscription.depth:=100",
    "qos_overrides./tilted/base/pose.subscription.depth:=100",
)
REASONS = (
    "non_finite",
    "quaternion",
    "stale",
    "future",
    "duplicate",
    "out_of_order",
    "no_base",
    "base_stale",
    "workspace",
    "jump",
)
TILTED, TILTED_BASE = "tilted_bridge: platform", "tilted_bridge: base"

Values = dict[str, str]


def start_bridge(
    params: Sequence[str], remaps: Sequence[str] = ("__ns:=/hsa",)
) -> subprocess.Popen:
    """A mocap_bridge process (default: in namespace /hsa) with ``name:=value`` parameters."""
    return start_node("hsa_mocap_bridge", "mocap_bridge", params, remaps)


@pytest.fixture(scope="module")
def bridges() -> Iterator[None]:
    """Two bridges, started together: the shared one in /hsa (configured base at BASE, rest-pose
    check on) for the tests that stream samples into it, and TILTED (measured base pose, its own
    name, namespace and mocap topics)."""
    procs = [
        start_bridge([*COMMON, f"base_position:={list(BASE)}", "rest_check:=true"]),
        start_bridge(
            [*COMMON, "use_base_pose:=true", *TILTED_TOPICS],
            ["__node:=tilted_bridge", "__ns:=/tilted"],
        ),
    ]
    for proc in procs:
        wait_for_line(proc, "ready", timeout=120.0)
    yield
    assert [stop_process(proc) for proc in procs] == [0, 0]


def pose_msg(stamp_ns: int, position: Sequence[float], quaternion: Sequence[float]) -> PoseStamped:
    """A world-frame PoseStamped."""
    msg = PoseStamped()
    msg.header.stamp = Time(nanoseconds=stamp_ns).to_msg()
    msg.header.frame_id = "world"
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
    return msg


def _world(chiee: Sequence[float], base: Sequence[float] = BASE) -> tuple[np.ndarray, np.ndarray]:
    """World position and quaternion of the platform for a planar pose (default frame chain,
    configured base)."""
    return mocap.planar_to_world(chiee, base)


def _trajectory(n: int) -> np.ndarray:
    """n known planar poses at 200 Hz starting at the rest pose [0, 0.110, 0]: a 1 Hz sway."""
    w = 2.0 * math.pi * np.arange(n) * 0.005
    return np.stack([0.02 * np.sin(w), 0.110 + 0.005 * (1.0 - np.cos(w)), -0.2 * np.sin(w)], axis=1)


def stream(pub: object, messages: Sequence[object], period: float = 0.005) -> None:
    """Publish messages paced at one per period (wall clock)."""
    start = time.monotonic()
    for k, msg in enumerate(messages):
        delay = start + k * period - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
        pub.publish(msg)  # type: ignore[attr-defined]


def stamp_ns(msg: PlanarPoseStamped) -> int:
    """Header stamp [ns]."""
    return Time.from_msg(msg.header.stamp).nanoseconds


def _planar(msg: PlanarPoseStamped) -> list[float]:
    """[x, y, theta] of an ee_pose message."""
    return [msg.pose.x, msg.pose.y, msg.pose.theta]


def _setup(
    node: Node, ns: str = "/hsa", platform_topic: str = "/mocap/platform/pose"
) -> tuple[object, list[PlanarPoseStamped], list[DiagnosticArray]]:
    """Mocap publisher, ee_pose collector and /diagnostics collector of the test node, matched with
    the bridge."""
    diagnostics: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 50)
    received: list[PlanarPoseStamped] = []
    sub = node.create_subscription(PlanarPoseStamped, f"{ns}/ee_pose", received.append, RECEIVE)
    pub = node.create_publisher(PoseStamped, platform_topic, qos.SENSOR)
    assert wait_until(
        lambda: pub.get_subscription_count() >= 1 and sub.get_publisher_count() >= 1
    ), "not matched"
    return pub, received, diagnostics


def statuses(
    diagnostics: list[DiagnosticArray], name: str = STATUS, after_ns: int = 0
) -> list[tuple[DiagnosticStatus, Values]]:
    """Statuses called name received so far (from reports issued after after_ns), with their
    values."""
    return [
        (s, {kv.key: kv.value for kv in s.values})
        for a in list(diagnostics)
        for s in a.status
        if s.name == name and Time.from_msg(a.header.stamp).nanoseconds > after_ns
    ]


def status(
    diagnostics: list[DiagnosticArray],
    accept: Callable[[DiagnosticStatus, Values], bool] = lambda s, v: True,
    name: str = STATUS,
    after_ns: int = 0,
    timeout: float = 10.0,
) -> tuple[DiagnosticStatus, Values]:
    """Wait for the first status called name (issued after after_ns) that ``accept`` takes; return
    it and its values."""
    found: list[tuple[DiagnosticStatus, Values]] = []

    def _match() -> bool:
        found[:] = [(s, v) for s, v in statuses(diagnostics, name, after_ns) if accept(s, v)]
        return bool(found)

    if not wait_until(_match, timeout):
        pytest.fail(f"no matching {name!r} status; last seen: {statuses(diagnostics, name)[-1:]}")
    return found[0]


def prime(
    node: Node,
    pub: object,
    diagnostics: list[DiagnosticArray],
    sample: Callable[[int], PoseStamped],
    key: str = "received",
    echo: list[PlanarPoseStamped] | None = None,
    name: str = STATUS,
) -> Values:
    """Publish sample(now) every 50 ms until the bridge's counter ``key`` grows (and ``echo`` got an
    ee_pose), i.e. the bridge has matched this publisher (discovery may drop the first samples);
    return the counts of a report issued afterwards: the baseline of the test's counts."""
    start = int(
        status(diagnostics, name=name, after_ns=node.get_clock().now().nanoseconds)[1].get(key, 0)
    )
    deadline = time.monotonic() + 20.0
    while int(statuses(diagnostics, name)[-1][1].get(key, 0)) <= start or (
        echo is not None and not echo
    ):
        assert time.monotonic() < deadline, "the bridge never reacted to the priming samples"
        pub.publish(sample(node.get_clock().now().nanoseconds))  # type: ignore[attr-defined]
        time.sleep(0.05)
    return status(diagnostics, name=name, after_ns=node.get_clock().now().nanoseconds + 50_000_000)[
        1
    ]


def delta(values: Values, baseline: Values, key: str) -> int:
    """Change of a counter since the baseline."""
    return int(values[key]) - int(baseline[key])


def test_known_poses_come_out_exactly_with_the_input_stamps(bridges, ros_node) -> None:
    pub, received, diagnostics = _setup(ros_node)
    rest = _world(mocap.REST_POSE)
    baseline = prime(ros_node, pub, diagnostics, lambda t: pose_msg(t, *rest), echo=received)
    received.clear()

    t0 = ros_node.get_clock().now().nanoseconds
    known = {t0 + k * PERIOD_NS: c for k, c in enumerate(_trajectory(400))}
    stream(pub, [pose_msg(t, *_world(c)) for t, c in known.items()])

    t_end = ros_node.get_clock().now().nanoseconds
    # the report that counts all 400, however late a loaded machine delivers them
    _, values = status(
        diagnostics,
        lambda s, v: delta(v, baseline, "received") >= 400,
        after_ns=t_end,
        timeout=30.0,
    )
    assert (
        delta(values, baseline, "received") == 400 and delta(values, baseline, "published") == 400
    )
    assert all(delta(values, baseline, f"rejected_{reason}") == 0 for reason in REASONS)
    assert wait_until(lambda: len(received) == 400, 30.0), f"{len(received)} of 400 poses arrived"
    assert [stamp_ns(m) for m in received] == list(known)
    for msg in received:
        assert msg.header.frame_id == "hsa_base"
        np.testing.assert_allclose(_planar(msg), known[stamp_ns(msg)], rtol=0.0, atol=1e-9)

    rates = [float(v["output_rate_hz"]) for _, v in statuses(diagnostics)]
    # 200 Hz nominally; generous on a busy machine
    assert max(rates) > 100.0, f"output rates {rates}"
    rest_status, _ = status(diagnostics, name="mocap_bridge: rest pose", after_ns=t0)
    assert rest_status.level == DiagnosticStatus.OK, rest_status.message
    stale, values = status(
        diagnostics, lambda s, v: s.level == DiagnosticStatus.ERROR, after_ns=t_end
    )
    assert "stale" in stale.message and float(values["time_since_last_sample_s"]) > 0.25


def test_invalid_samples_are_dropped_and_counted(bridges, ros_node) -> None:
    pub, received, diagnostics = _setup(ros_node)
    chiee = _trajectory(60)
    baseline = prime(
        ros_node, pub, diagnostics, lambda t: pose_msg(t, *_world(chiee[0])), echo=received
    )
    received.clear()

    t0 = ros_node.get_clock().now().nanoseconds
    slot = [t0 + k * PERIOD_NS for k in range(60)]
    last_good = chiee[19]
    position, quaternion = _world(last_good)
    bad = {
        # 3 cm in 5 ms (limit 2 cm)
        "jump": pose_msg(slot[20], *_world(last_good + [0.03, 0.0, 0.0])),
        "non_finite": pose_msg(slot[21], (math.nan, *position[1:]), quaternion),
        "quaternion": pose_msg(slot[22], position, 1.1 * quaternion),
        "duplicate": pose_msg(slot[19], *_world(last_good + [0.001, 0.0, 0.0])),
        "out_of_order": pose_msg(slot[19] - 2_000_000, *_world(last_good)),
        "workspace": pose_msg(slot[23], *_world([0.0, 0.25, 0.0])),
        "stale": pose_msg(slot[24] - 2_000_000_000, *_world(last_good)),
        "future": pose_msg(slot[24] + 2_000_000_000, *_world(last_good)),
    }
    good = [pose_msg(slot[k], *_world(chiee[k])) for k in range(60)]
    stream(pub, [*good[:20], *bad.values(), *good[28:]])

    _, values = status(diagnostics, lambda s, v: delta(v, baseline, "received") == 60, timeout=30.0)
    assert {
        reason: delta(values, baseline, f"rejected_{reason}") for reason in bad
    } == dict.fromkeys(bad, 1)
    assert (
        delta(values, baseline, "published") == 52
        and delta(values, baseline, "rejected_no_base") == 0
    )
    assert wait_until(lambda: len(received) == 52, 30.0), f"{len(received)} of 52 poses arrived"
    assert [stamp_ns(m) for m in received] == slot[:20] + slot[28:]
    for msg in received:
        np.testing.assert_allclose(
            _planar(msg), chiee[slot.index(stamp_ns(msg))], rtol=0.0, atol=1e-9
        )


def test_refused_run_time_update_keeps_the_old_value(bridges, ros_node) -> None:
    params = ParameterClient(ros_node, "/hsa/mocap_bridge")
    set_one, get = params.set, params.get

    for name, value in (
        ("workspace_y", [0.18, 0.06]),
        ("max_jump", -0.5),
        ("use_base_pose", True),
        ("base_quaternion", [0.0, 0.0, 0.0, 0.9]),
    ):
        result = set_one(name, value)
        assert not result.successful and name in result.reason, result.reason
    assert (
        get("workspace_y") == [0.06, 0.18]
        and get("max_jump") == 0.02
        and get("use_base_pose") is False
    )

    assert set_one(
        "workspace_y", [0.12, 0.18]
    ).successful  # accepted: the rest pose (y = 0.110) is now outside
    try:
        pub, received, diagnostics = _setup(ros_node)
        rest = _world(mocap.REST_POSE)
        baseline = prime(ros_node, pub, diagnostics, lambda t: pose_msg(t, *rest))
        t0 = ros_node.get_clock().now().nanoseconds
        stream(pub, [pose_msg(t0 + k * PERIOD_NS, *rest) for k in range(10)])
        _, values = status(diagnostics, lambda s, v: delta(v, baseline, "received") == 10)
        assert delta(values, baseline, "rejected_workspace") == 10 and not received
    finally:
        assert set_one(
            "workspace_y", [0.06, 0.18]
        ).successful  # the shared bridge serves other tests


def _tilted_base() -> tuple[tuple[float, float, float], np.ndarray]:
    """World position and quaternion of a tilted, turned base body."""
    turn = np.array(
        [[math.cos(0.1), -math.sin(0.1), 0.0], [math.sin(0.1), math.cos(0.1), 0.0], [0.0, 0.0, 1.0]]
    )
    return (0.5, 1.3, 0.2), mocap.matrix_to_quaternion(turn @ mocap.rotation_x(0.05))


def stream_frames(
    node: Node,
    frames: Sequence[Callable[[int], Sequence[tuple[object, PoseStamped]]]],
    period: float = 0.005,
) -> list[int]:
    """Publish frame k's (publisher, message) pairs, made from the node clock's time, at one frame
    per period (wall clock); return the stamps used."""
    start, stamps = time.monotonic(), []
    for k, frame in enumerate(frames):
        delay = start + k * period - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)
        stamps.append(node.get_clock().now().nanoseconds)
        for pub, msg in frame(stamps[-1]):
            pub.publish(msg)  # type: ignore[attr-defined]
    return stamps


def test_measured_base_pose_with_tilt(bridges, ros_node) -> None:
    pub, received, diagnostics = _setup(ros_node, "/tilted", "/tilted/platform/pose")
    base_pub = ros_node.create_publisher(PoseStamped, "/tilted/base/pose", qos.SENSOR)
    base, base_quaternion = _tilted_base()
    config = mocap.MocapConfig(use_base_orientation=True)
    chiee = _trajectory(200)
    platform = [mocap.planar_to_world(c, base, config, base_quaternion) for c in chiee]

    # without a base pose, platform samples are dropped as no_base
    baseline = prime(ros_node, pub, diagnostics, lambda t: pose_msg(t, *platform[0]), name=TILTED)
    t0 = ros_node.get_clock().now().nanoseconds
    stream(pub, [pose_msg(t0 + k * PERIOD_NS, *platform[k]) for k in range(5)])
    _, values = status(diagnostics, lambda s, v: delta(v, baseline, "received") == 5, name=TILTED)
    assert delta(values, baseline, "rejected_no_base") == 5 and values["published"] == "0"
    waiting, _ = status(diagnostics, name=TILTED_BASE)
    assert waiting.level == DiagnosticStatus.WARN and "waiting" in waiting.message

    prime(
        ros_node,
        base_pub,
        diagnostics,
        lambda t: pose_msg(t, base, base_quaternion),
        key="accepted",
        name=TILTED_BASE,
    )
    known: dict[int, np.ndarray] = {}

    t0 = ros_node.get_clock().now().nanoseconds

    def frame(k: int) -> Callable[[int], list[tuple[object, PoseStamped]]]:
        def make(
            _: int,
        ) -> list[tuple[object, PoseStamped]]:  # stamps on the 200 Hz grid: exact jump bounds
            t = t0 + k * PERIOD_NS
            known[t] = chiee[k]
            return [
                (base_pub, pose_msg(t, base, base_quaternion)),
                (pub, pose_msg(t, *platform[k])),
            ]

        return make

    stream_frames(ros_node, [frame(k) for k in range(200)])
    assert wait_until(lambda: len(received) >= 150, 30.0), (
        f"only {len(received)} of 200 poses arrived"
    )
    for msg in received:
        np.testing.assert_allclose(_planar(msg), known[stamp_ns(msg)], rtol=0.0, atol=1e-9)
    _, values = status(diagnostics, name=TILTED, after_ns=ros_node.get_clock().now().nanoseconds)
    assert values["rejected_jump"] == values["rejected_workspace"] == "0"
    live, values = status(
        diagnostics, lambda s, v: s.level == DiagnosticStatus.OK, name=TILTED_BASE, after_ns=t0
    )
    assert values["mode"] == "live"
    assert all(
        values[f"rejected_{reason}"] == "0"
        for reason in ("frame", "stale", "future", "out_of_order")
    )


def test_base_poses_are_checked_and_a_stale_base_is_never_used(bridges, ros_node) -> None:
    """Issue 22: base poses stamped 1970, 0.4 s ahead or out of order, 5 mm off, are dropped and
    counted; without base poses for base_timeout (0.25 s) the bridge stops publishing (base mode
    stale, ERROR) and resumes when they return."""
    from tests.ros.faults import fault  # faults imports this module

    pub, received, diagnostics = _setup(ros_node, "/tilted", "/tilted/platform/pose")
    base_pub = ros_node.create_publisher(PoseStamped, "/tilted/base/pose", qos.SENSOR)
    base, base_quaternion = _tilted_base()
    shifted = (
        *base[:2],
        base[2] + 0.005,  # 5 mm in the plane: moved the EE estimate by 6.4 mm when accepted
    )
    rest = mocap.planar_to_world(
        mocap.REST_POSE, base, mocap.MocapConfig(use_base_orientation=True), base_quaternion
    )
    bad = {
        "stale": lambda t: t % 10**9,  # 1970
        "future": lambda t: t + 400_000_000,
        "out_of_order": lambda t: t - 2_000_000,
    }

    def frame(
        with_base: bool, with_bad: bool = False
    ) -> Callable[[int], list[tuple[object, PoseStamped]]]:
        def make(t: int) -> list[tuple[object, PoseStamped]]:
            pairs = [(base_pub, pose_msg(t, base, base_quaternion))] if with_base else []
            if with_bad:
                pairs += [
                    (base_pub, pose_msg(stamp(t), shifted, base_quaternion))
                    for stamp in bad.values()
                ]
            return [*pairs, (pub, pose_msg(t, *rest))]

        return make

    before = prime(
        ros_node,
        base_pub,
        diagnostics,
        lambda t: pose_msg(t, base, base_quaternion),
        key="accepted",
        name=TILTED_BASE,
    )
    received.clear()
    sent = stream_frames(ros_node, [frame(True, True)] * 100)
    # the report that counts 50 of each, however late a loaded machine delivers them
    _, values = status(
        diagnostics,
        lambda s, v: all(delta(v, before, f"rejected_{reason}") >= 50 for reason in bad),
        name=TILTED_BASE,
        after_ns=sent[-1],
        timeout=30.0,
    )
    rejected = {reason: delta(values, before, f"rejected_{reason}") for reason in bad}
    assert all(n >= 50 for n in rejected.values()), (
        rejected,
        values,  # best effort: a loaded machine may lose some
    )
    assert delta(values, before, "accepted") + sum(rejected.values()) == delta(
        values, before, "received"
    ), values
    assert delta(values, before, "accepted") <= 100, values  # the genuine ones at most
    assert wait_until(lambda: len(received) >= 90, 30.0), (
        f"only {len(received)} of 100 poses arrived"
    )
    for msg in received:  # the shifted base poses never entered the frame chain
        np.testing.assert_allclose(_planar(msg), mocap.REST_POSE, rtol=0.0, atol=1e-9)

    platform_before = status(
        diagnostics, name=TILTED, after_ns=ros_node.get_clock().now().nanoseconds
    )[1]
    received.clear()
    last_base = stream_frames(ros_node, [frame(True)])[-1]
    # 0.6 s of platform poses without a base pose
    silent = stream_frames(ros_node, [frame(False)] * 120)
    stale, values = status(
        diagnostics,
        lambda s, v: s.level == DiagnosticStatus.ERROR,
        name=TILTED_BASE,
        after_ns=silent[-1],
    )
    assert values["mode"] == "stale" and "stale" in stale.message, stale.message
    _, platform_values = status(diagnostics, name=TILTED, after_ns=silent[-1])
    assert delta(platform_values, platform_before, "rejected_base_stale") > 0, platform_values
    late = [
        (stamp_ns(m) - last_base) * 1e-9 for m in received if stamp_ns(m) - last_base > 250_000_000
    ]
    assert not late, (
        f"platform poses published {late[:3]} s after the last base pose (base_timeout 0.25 s)"
    )
    last_out = max(((stamp_ns(m) - last_base) * 1e-9 for m in received), default=float("nan"))

    n = len(received)
    back = stream_frames(ros_node, [frame(True)] * 60)
    assert wait_until(lambda: len(received) > n + 30, 30.0), (
        "publishing did not resume with the base poses"
    )
    live, _ = status(
        diagnostics,
        lambda s, v: s.level == DiagnosticStatus.OK,
        name=TILTED_BASE,
        after_ns=back[-1],
    )
    assert "live" in live.message
    fault(
        "base poses stamped 1970, +0.4 s or out of order, 5 mm off",
        f"dropped {rejected}, 0 used, ee_pose exact",
        "next valid base sample",
    )
    fault(
        "no base pose for 0.6 s (base_timeout 0.25 s)",
        f"base mode stale (ERROR); last ee_pose stamped {last_out:.3f} s after the last base pose",
        "with the first valid base sample",
    )


def test_bad_start_parameters_exit_2_naming_the_parameter() -> None:
    bad = {
        "max_jump": "max_jump:=-1.0",  # outside the declared range (rclpy refuses)
        # not a unit quaternion (validator)
        "base_quaternion": "base_quaternion:=[0.0, 0.0, 0.0, 0.5]",
    }
    assert_refused_at_start({name: start_bridge([param]) for name, param in bad.items()})

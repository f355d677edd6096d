"""mocap_bridge stamps and frames (issue 10, item 5) as a real process fed a live 200 Hz stream by
the test: one pose stamped 0.4 s in the future must not blind the bridge to the genuine samples
after it; poses in a wrong frame are dropped and counted, not relabelled; drops are logged
throttled; malformed CDR on the topic prints nothing."""

from __future__ import annotations

import re
import struct
import time
from collections.abc import Iterator

import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rclpy.time import Time

from hsa_common import qos
from hsa_msgs.msg import PlanarPoseStamped
from tests.ros.faults import (
    BEST_EFFORT,
    OFFSET_CHIEE,
    DiagnosticsLog,
    MocapStream,
    NodeProcess,
    Recorder,
    fault,
    start_all,
    wait_until,
)
from tests.ros.test_mocap_bridge import pose_msg

pytestmark = pytest.mark.ros

NS = "/stamps"
TOPIC = f"{NS}/mocap/platform/pose"
BRIDGE = "mocap_bridge: platform"
FUTURE_NS = 400_000_000  # +0.4 s: inside max_age (0.5 s), the incident of issue 10
DROP_LOG = "dropped platform sample"


@pytest.fixture(scope="module")
def bridge() -> Iterator[NodeProcess]:
    """A mocap_bridge in /stamps with default checks, diagnostics at 5 Hz and a deep input queue."""
    procs = start_all(
        {
            "bridge": (
                "mocap_bridge",
                [
                    "-r",
                    f"__ns:={NS}",
                    "-p",
                    f"platform_topic:={TOPIC}",
                    "-p",
                    "diagnostics_period:=0.2",
                    "-p",
                    f"qos_overrides.{TOPIC}.subscription.depth:=100",
                ],
            )
        }
    )
    yield procs["bridge"]
    assert procs["bridge"].stop() == 0


def _stamp(msg: PlanarPoseStamped) -> int:
    """Header stamp [ns]."""
    return Time.from_msg(msg.header.stamp).nanoseconds


def _delta(after: dict[str, str], before: dict[str, str], key: str) -> int:
    """Growth of a counter between two reports (0 if not reported)."""
    return int(after.get(key, 0)) - int(before.get(key, 0))


def _report(diagnostics: DiagnosticsLog, node) -> dict[str, str]:  # noqa: ANN001 - rclpy node
    """Values of the first bridge report issued from now on."""
    return diagnostics.wait(BRIDGE, after_ns=node.get_clock().now().nanoseconds)[1]


def _started(ros_node, bridge: NodeProcess) -> tuple[MocapStream, Recorder, DiagnosticsLog]:  # noqa: ANN001
    """A running 200 Hz stream whose poses come out of the bridge, the ee_pose recorder and the
    diagnostics log."""
    poses = Recorder(ros_node, PlanarPoseStamped, f"{NS}/ee_pose", BEST_EFFORT)
    diagnostics = DiagnosticsLog(ros_node)
    stream = MocapStream(ros_node, TOPIC, OFFSET_CHIEE)
    if not wait_until(lambda: len(poses) > 20, 20.0):
        stream.close()
        pytest.fail(f"the bridge published nothing:\n{bridge.output()}")
    return stream, poses, diagnostics


def _future_window(
    stream: MocapStream, poses: Recorder, diagnostics: DiagnosticsLog, node: Node
) -> tuple[int, list[int], list[int], dict[str, str], dict[str, str]]:
    """Inject one pose stamped FUTURE_NS after a regular sample and wait (30 s bound each) until
    the stream has sent past the next FUTURE_NS and the bridge has published a sample from after
    it. Return the regular sample's stamp, the genuine stamps of the window, the bridge's output
    stamps since the injection and its reports before and after."""
    injected: list[int] = []
    before = _report(diagnostics, node)
    n_poses = len(poses)

    def future(stamp: int) -> PoseStamped:
        injected.append(stamp)
        return pose_msg(stamp + FUTURE_NS, *stream.world)

    stream.inject(future)
    assert wait_until(lambda: injected, 30.0)
    s = injected[0]
    # on the old code every genuine sample of this window was refused
    assert wait_until(lambda: stream.sent[-1] > s + FUTURE_NS, 30.0)
    assert wait_until(lambda: any(_stamp(m) > s + FUTURE_NS for m in poses.since(n_poses)), 30.0), (
        "the bridge published nothing after the window"
    )
    after = _report(diagnostics, node)
    genuine = [t for t in stream.sent if s < t <= s + FUTURE_NS]
    return s, genuine, [_stamp(m) for m in poses.since(n_poses)], before, after


def test_one_future_stamp_does_not_blind_the_bridge(bridge, ros_node) -> None:
    stream, poses, diagnostics = _started(ros_node, bridge)
    try:
        # the window must hold >= 60 genuine samples: the test's own 200 Hz stream can fall short
        # when a loaded machine deschedules the test process, and then the window is set up again
        # (at most three times)
        for _ in range(3):
            s, genuine, out, before, after = _future_window(stream, poses, diagnostics, ros_node)
            if len(genuine) >= 60:
                break
    finally:
        stream.close()
    assert _delta(after, before, "rejected_future") == 1, after
    assert _delta(after, before, "rejected_out_of_order") == 0, after
    assert s + FUTURE_NS not in out, "the future-stamped pose was published"
    published = [t for t in genuine if t in out]
    assert len(genuine) >= 60, f"the stream sent only {len(genuine)} samples in 0.4 s, 3 times"
    following = [t for t in out if t > s]
    assert following and following[0] in genuine[:2], (
        "the first or second genuine sample after the future stamp must be published: "
        f"{genuine[:2]} vs {following[:2]}"
    )
    assert len(published) >= 0.9 * len(genuine), (
        f"{len(published)} of {len(genuine)} genuine samples published"
    )
    assert all(b > a for a, b in zip(out, out[1:])), "ee_pose stamps must increase"
    fault(
        "mocap pose stamped +0.4 s (inside max_age)",
        f"dropped (rejected_future), {len(published)} of "
        f"{len(genuine)} genuine samples in the next 0.4 s published",
        (published[0] - s) * 1e-9,
    )


def test_wrong_frame_is_dropped_counted_and_logged_throttled(bridge, ros_node) -> None:
    stream, poses, diagnostics = _started(ros_node, bridge)
    wrong: list[int] = []
    n_wrong = 200
    try:
        before = _report(diagnostics, ros_node)
        n_poses = len(poses)

        def in_frame(frame_id: str):  # noqa: ANN202 - a MocapStream injection
            def make(stamp: int) -> PoseStamped:
                # 1 ns after a genuine sample: only the frame is wrong
                msg = pose_msg(stamp + 1, *stream.world)
                msg.header.frame_id = frame_id
                wrong.append(stamp + 1)
                return msg

            return make

        for k in range(n_wrong):
            stream.inject(in_frame(("map", "")[k % 2]))
            time.sleep(0.005)
        assert wait_until(lambda: len(wrong) == n_wrong, 30.0)
        # the first report that counts them all, however late a loaded machine delivers them
        after = diagnostics.wait(
            BRIDGE,
            lambda s, v: _delta(v, before, "rejected_frame") >= n_wrong,
            after_ns=ros_node.get_clock().now().nanoseconds,
            timeout=30.0,
        )[1]
    finally:
        stream.close()
    out = {_stamp(m) for m in poses.since(n_poses)}
    assert _delta(after, before, "rejected_frame") == n_wrong, after
    assert not out & set(wrong), "a pose in a wrong frame was published"
    assert "frame_id" in after["last_rejection"], after["last_rejection"]
    assert {m.header.frame_id for m in poses.since(n_poses)} == {"hsa_base"}

    # 200 drops in about 1 s: the bridge logs a drop at most once per 5 s (its output reaches this
    # test through a pipe and a reader thread)
    assert wait_until(lambda: bool(bridge.log(DROP_LOG)), 30.0), bridge.output()
    times = [float(re.search(r"\[(\d+\.\d+)\]", line).group(1)) for line in bridge.log(DROP_LOG)]
    assert times and all(b - a >= 4.9 for a, b in zip(times, times[1:])), bridge.log(DROP_LOG)
    fault(
        "mocap pose with frame_id 'map' or ''",
        "dropped (rejected_frame), not relabelled; one WARN per 5 s",
        "next sample",
    )


def test_malformed_cdr_prints_nothing_and_the_stream_goes_on(bridge, ros_node) -> None:
    stream, poses, diagnostics = _started(ros_node, bridge)
    raw = ros_node.create_publisher(PoseStamped, TOPIC, qos.SENSOR)
    good = serialize_message(PoseStamped())
    malformed = [
        good[:30],
        b"\x00\x01\x00\x00" + b"\xff" * 40,
        b"\x00\x01",
        # truncated, garbage, short, huge string
        good[:12] + struct.pack("<I", 0x7FFFFFFF) + good[16:],
    ]
    try:
        lines = len(bridge.lines)
        for k in range(100):
            raw.publish(malformed[k % len(malformed)])
            time.sleep(0.002)
        n_poses = len(poses)
        assert wait_until(lambda: len(poses) > n_poses + 50, 10.0), "the stream stopped"
    finally:
        stream.close()
    printed = "".join(bridge.lines[lines:])
    assert "Traceback" not in printed and "Error" not in printed, printed

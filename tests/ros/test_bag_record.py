"""bag_recorder as a process: what it writes is read back by independent readers (mcap + mcap_ros2,
rosbags).

Covers standard and hsa_msgs types, a latched topic published before the recorder started, a late
publisher, QoS adaptation to a best-effort publisher that joins later, split bags with a SIGTERM
close, a SIGKILL mid-run (the bag is readable up to the last flush, and complete after bag_recover),
and the refusal to overwrite a bag.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from std_msgs.msg import String, UInt32

from hsa_bag.storage import read_metadata
from hsa_common import qos
from hsa_common.launcher import find_executable
from hsa_msgs.msg import PlanarState, Setpoint
from tests.ros.conftest import start_process, stop_process, wait_for_line, wait_until
from tests.ros.faults import DiagnosticsLog

pytestmark = pytest.mark.ros

UINT32 = "std_msgs/msg/UInt32"
RECORDING = "bag_recorder: recording"


@pytest.fixture
def recorder() -> Iterator[Callable[..., subprocess.Popen]]:
    """Start bag_recorder processes (output + extra parameters) and wait for 'ready'; all stopped at
    teardown."""
    procs: list[subprocess.Popen] = []

    def _start(output: Path, *params: str, ready: bool = True) -> subprocess.Popen:
        args = [find_executable("hsa_bag", "bag_recorder"), "--ros-args", "-p", f"output:={output}"]
        for param in params:
            args += ["-p", param]
        proc = start_process(args)
        procs.append(proc)
        if ready:
            wait_for_line(proc, "ready")
        return proc

    yield _start
    for proc in procs:
        stop_process(proc)


def wait_recorded(node: Node, topics: list[str], timeout: float = 30.0) -> None:
    """Wait until bag_recorder has subscribed to every topic (it does once a topic has a
    publisher)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(
            any(s.node_name == "bag_recorder" for s in node.get_subscriptions_info_by_topic(t))
            for t in topics
        ):
            return
        time.sleep(0.05)
    pytest.fail(f"bag_recorder did not subscribe to all of {topics}")


def wait_matched(pub: Publisher, timeout: float = 30.0) -> None:
    """Wait until ``pub`` has a matched subscription."""
    deadline = time.monotonic() + timeout
    while pub.get_subscription_count() == 0:
        assert time.monotonic() < deadline, f"no subscription matched {pub.topic_name}"
        time.sleep(0.05)


def decoded(bag: Path) -> dict[str, list[tuple[int, object]]]:
    """(log time, message) per topic of every file of a bag, read with the `mcap` package and
    mcap_ros2 decoding."""
    out: dict[str, list[tuple[int, object]]] = {}
    for file in sorted(bag.glob("*.mcap")):
        with open(file, "rb") as handle:
            for item in make_reader(
                handle, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages():
                out.setdefault(item.channel.topic, []).append(
                    (item.message.log_time, item.decoded_message)
                )
    return out


def test_records_standard_custom_latched_and_late_topics(
    ros_node: Node, recorder, tmp_path: Path
) -> None:
    bag = tmp_path / "run"
    latched = ros_node.create_publisher(Setpoint, "/hsa/setpoint", qos.LATCHED)
    setpoint = Setpoint(trajectory_length=11, trajectory_index=3)
    setpoint.chiee_des.x = 0.01
    # before the recorder exists: only transient-local delivery can record it
    latched.publish(setpoint)
    state = ros_node.create_publisher(PlanarState, "/hsa/state", qos.SENSOR)
    joints = ros_node.create_publisher(JointState, "/hsa/motor_states", qos.SENSOR)
    chatter = ros_node.create_publisher(String, "/chatter", 10)
    proc = recorder(bag)
    wait_recorded(ros_node, ["/hsa/setpoint", "/hsa/state", "/hsa/motor_states", "/chatter"])
    for pub in (state, joints, chatter):
        wait_matched(pub)

    before = time.time_ns()
    for i in range(100):
        msg = PlanarState(window_samples=i, velocity_valid=True)
        msg.q.kappa_be = 0.1 * i
        state.publish(msg)
        if i % 5 == 0:
            joints.publish(
                JointState(name=[f"motor_{21 + k}" for k in range(4)], position=[float(i)] * 4)
            )
            chatter.publish(String(data=f"hello {i // 5}"))
        time.sleep(0.005)
    after = time.time_ns()

    late = ros_node.create_publisher(String, "/late", 10)  # appears while recording
    wait_recorded(ros_node, ["/late"])
    wait_matched(late)
    for i in range(5):
        late.publish(String(data=f"late {i}"))
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    weak = ros_node.create_publisher(String, "/chatter", best_effort)
    # incompatible with the reliable subscription: matches once the recorder re-subscribes
    wait_matched(weak)
    for i in range(5):
        weak.publish(String(data=f"weak {i}"))
    time.sleep(1.0)
    assert stop_process(proc) == 0
    output = proc.stdout.read() if proc.stdout else ""
    assert f"to {bag}" in output and "re-subscribed /chatter" in output

    got = decoded(bag)  # independent reader 1: mcap + mcap_ros2
    assert "/rosout" not in got and "/parameter_events" not in got
    latched_got = [
        (m.trajectory_length, m.trajectory_index, m.chiee_des.x) for _, m in got["/hsa/setpoint"]
    ]
    assert latched_got == [(11, 3, 0.01)]
    states = [m for _, m in got["/hsa/state"]]
    assert len(states) >= 95  # best effort on loopback: practically all
    assert [m.window_samples for m in states] == sorted(m.window_samples for m in states)
    assert all(m.q.kappa_be == pytest.approx(0.1 * m.window_samples) for m in states)
    # receive time, node clock
    assert all(before <= t <= after + 2 * 10**9 for t, _ in got["/hsa/state"])
    assert [m.position[0] for _, m in got["/hsa/motor_states"]] == [
        float(i) for i in range(0, 100, 5)
    ]
    assert got["/hsa/motor_states"][0][1].name == ["motor_21", "motor_22", "motor_23", "motor_24"]
    chat = [m.data for _, m in got["/chatter"]]
    assert chat[:20] == [f"hello {i}" for i in range(20)] and [
        c for c in chat if c.startswith("weak")
    ]
    assert [m.data for _, m in got["/late"]] == [f"late {i}" for i in range(5)]

    with Reader(
        bag
    ) as reader:  # independent reader 2: rosbags, with the QoS the publishers offered
        topics = reader.topics
        assert {t: topics[t].msgcount for t in got} == {t: len(v) for t, v in got.items()}
        qos_of = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
        assert qos_of["/hsa/setpoint"].durability.name == "TRANSIENT_LOCAL"
        assert qos_of["/hsa/setpoint"].reliability.name == "RELIABLE"
        assert qos_of["/hsa/state"].reliability.name == "BEST_EFFORT"
        assert topics["/hsa/state"].msgtype == "hsa_msgs/msg/PlanarState"


def counter_stream(
    pub: Publisher, rate: float, seconds: float
) -> tuple[threading.Thread, list[int]]:
    """A thread publishing UInt32 0, 1, 2, … at ``rate``; the list holds what was published so
    far."""
    sent: list[int] = []

    def run() -> None:
        start = time.monotonic()
        for i in range(round(rate * seconds)):
            time.sleep(max(0.0, start + i / rate - time.monotonic()))
            pub.publish(UInt32(data=i))
            sent.append(i)

    wait_matched(pub)
    return threading.Thread(target=run, daemon=True), sent


def counters(messages: list[tuple[int, bytes]]) -> list[int]:
    """Deserialized UInt32 values."""
    store = get_typestore(Stores.ROS2_JAZZY)
    return [store.deserialize_cdr(data, UINT32).data for _, data in messages]


def test_split_bag_closed_by_sigterm(ros_node: Node, recorder, tmp_path: Path) -> None:
    bag = tmp_path / "split"
    pub = ros_node.create_publisher(UInt32, "/counter", 100)
    proc = recorder(bag, "topics:=[/counter]", "max_bag_duration:=0.5")
    wait_recorded(ros_node, ["/counter"])
    diagnostics = DiagnosticsLog(ros_node)
    thread, sent = counter_stream(pub, 100.0, 2.0)
    thread.start()
    thread.join()
    # every message taken by the recorder, however late a loaded machine delivers them
    diagnostics.wait(RECORDING, lambda s, v: int(v["messages"]) >= len(sent), timeout=30.0)
    os.killpg(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=30) == 0

    files = sorted(
        (p for p in bag.iterdir() if p.suffix == ".mcap"),
        key=lambda p: int(p.stem.rsplit("_", 1)[1]),
    )
    assert len(files) >= 3 and [p.name for p in files] == [
        f"split_{k}.mcap" for k in range(len(files))
    ]
    values = []
    for file in files:  # every split is a complete MCAP on its own
        with open(file, "rb") as handle:
            values += [
                m.decoded_message.data
                for m in make_reader(
                    handle, decoder_factories=[DecoderFactory()]
                ).iter_decoded_messages()
            ]
    assert values == sent
    assert read_metadata(bag)["relative_file_paths"] == [p.name for p in files]
    with Reader(bag) as reader:
        assert counters([(t, d) for _, t, d in reader.messages()]) == sent


def test_sigkill_leaves_bag_readable_up_to_the_last_flush(
    ros_node: Node, recorder, tmp_path: Path
) -> None:
    bag = tmp_path / "killed"
    flush_period, rate = 0.2, 100.0
    pub = ros_node.create_publisher(UInt32, "/counter", 100)
    proc = recorder(
        bag, "topics:=[/counter]", "max_bag_duration:=1.0", f"flush_period:={flush_period}"
    )
    wait_recorded(ros_node, ["/counter"])
    thread, sent = counter_stream(pub, rate, 3.0)
    thread.start()
    # 2.6 s of the stream's schedule, however late a loaded machine runs its thread
    assert wait_until(lambda: len(sent) >= round(2.6 * rate), 30.0)
    # 1 s slack for a loaded machine
    sent_before_last_flush = len(sent) - round((flush_period + 1.0) * rate)
    os.killpg(proc.pid, signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL
    thread.join()

    with Reader(bag) as reader:  # the closed splits are listed and complete
        listed = counters([(t, d) for _, t, d in reader.messages()])
    assert len(listed) >= 100 and listed == list(range(len(listed)))
    open_split = sorted(bag.glob("*.mcap"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))[-1]
    flushed: list[bytes] = []
    with open(
        open_split, "rb"
    ) as handle:  # the unfinished split, read record by record by the `mcap` package
        try:
            for record in StreamReader(handle).records:
                if isinstance(record, Message):
                    flushed.append(record.data)
        except McapError:  # EndOfFile: the stream ends inside the record being written at the kill
            pass
    store = get_typestore(Stores.ROS2_JAZZY)
    flushed_values = [store.deserialize_cdr(d, UINT32).data for d in flushed]
    everything = listed + flushed_values
    assert everything == list(range(len(everything))) and len(everything) >= sent_before_last_flush

    result = subprocess.run(
        [find_executable("hsa_bag", "bag_recover"), str(bag)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert f"{open_split.name}: completed with {len(flushed_values)} messages" in result.stdout
    with Reader(bag) as reader:
        assert counters([(t, d) for _, t, d in reader.messages()]) == everything


def test_existing_output_is_refused(recorder, tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    proc = recorder(tmp_path / "taken", ready=False)
    assert proc.wait(timeout=60) == 2
    output = proc.stdout.read() if proc.stdout else ""
    assert "parameter 'output'" in output and "refusing to overwrite" in output
    assert list((tmp_path / "taken").iterdir()) == []
    assert f"'{tmp_path / 'taken'}/' for a new date-time bag inside it" in output


def test_output_ending_in_a_slash_gets_a_new_bag_per_start(recorder, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    for _ in range(
        2
    ):  # a graph started twice with the same bag_dir (the launch files' default ends in '/')
        assert stop_process(recorder(f"{runs}/")) == 0
    bags = sorted(runs.iterdir())
    assert len(bags) == 2 and all((bag / "metadata.yaml").is_file() for bag in bags), bags
    assert all(re.fullmatch(r"\d{8}-\d{6}(_2)?", bag.name) for bag in bags), bags

"""bag_player as a process: timing, order across files, rate, start offset, loop with /clock, topic
selection, remap.

The bag (200 Hz PlanarState best effort + 40 Hz ControllerInfo reliable, 2 s) is split into two
files whose order is the reverse of time order, so a player that plays file after file would be off
by a second. The timing bounds hold on a 2-core machine shared with other test runs (load average up
to ~10; benchmarks/bench_bag.py reports the actual figures): inter-arrival error against the bag
median ≤ 5 ms per topic and p99 ≤ 50 ms over both topics, every message within 300 ms of its
schedule.

Lockstep (``lockstep: true``): with a real bag_recorder as the barrier's participant, every message
is recorded at its log time and a participant in the test process sees /clock in order, from the
first log time to the last; a participant that stalls (SIGSTOP) or never comes fails the player with
an ERROR naming it and exit code 1 after ``barrier_timeout`` (10× that for the start).
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosgraph_msgs.msg import Clock

from hsa_bag import player
from hsa_bag.bagio import Bag
from hsa_bag.msgtypes import TypeRegistry
from hsa_bag.storage import SplitBagWriter, read_metadata
from hsa_common import lockstep, qos, rosenv, runner
from hsa_common.launcher import find_executable
from hsa_msgs.msg import ControllerInfo, PlanarState
from tests.ros.conftest import start_process, stop_process, wait_for_line

pytestmark = pytest.mark.ros

STATE, INFO = "/hsa/state", "/hsa/controller_info"
START_NS = 1_750_000_000 * 10**9
SPAN = 2.0
INFINITE = QosTime(9223372036, 854775807)
# the test process must not drop samples
DEEP = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)


def offer(reliability: QosReliability) -> Qos:
    """An offered profile as the graph reports it (history unknown, depth 0)."""
    return Qos(
        QosHistory.UNKNOWN,
        0,
        reliability,
        QosDurability.VOLATILE,
        INFINITE,
        INFINITE,
        QosLiveliness.AUTOMATIC,
        INFINITE,
        False,
    )


def stamp_of(ns: int) -> Time:
    """builtin_interfaces/Time of ns."""
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    """2 s of state (200 Hz, index in window_samples) and controller info (40 Hz, index in
    trajectory_index)."""
    messages = []
    for i in range(round(SPAN * 200)):
        t = START_NS + i * 5_000_000
        msg = PlanarState(window_samples=i)
        msg.header.stamp = stamp_of(t)
        messages.append((t, STATE, serialize_message(msg)))
    for i in range(round(SPAN * 40)):
        t = START_NS + i * 25_000_000
        msg = ControllerInfo()
        msg.header.stamp = stamp_of(t)
        msg.setpoint.trajectory_index = i
        messages.append((t, INFO, serialize_message(msg)))
    messages.sort()
    half = len(messages) // 2
    registry = TypeRegistry()
    for msgtype in ("hsa_msgs/msg/PlanarState", "hsa_msgs/msg/ControllerInfo"):
        registry.ensure(msgtype)
    size = sum(len(m[2]) for m in messages[half:])  # splits the bag into 2–3 files
    path = tmp_path_factory.mktemp("play") / "synthetic"
    writer = SplitBagWriter(path, registry.store, max_bytes=size, chunk_size=4_096)
    writer.open()
    handles = {
        STATE: writer.add_topic(
            STATE, "hsa_msgs/msg/PlanarState", [offer(QosReliability.BEST_EFFORT)]
        ),
        INFO: writer.add_topic(
            INFO, "hsa_msgs/msg/ControllerInfo", [offer(QosReliability.RELIABLE)]
        ),
    }
    for t, topic, data in [
        *messages[half:],
        *messages[:half],
    ]:  # second second first: file order != time order
        writer.write(handles[topic], t, data)
    writer.close()
    files = read_metadata(path)["files"]
    ends = [
        f["starting_time"]["nanoseconds_since_epoch"] + f["duration"]["nanoseconds"] for f in files
    ]
    # the first file holds later messages than the last
    assert len(ends) >= 2 and ends[0] - ends[-1] > 0.5e9
    return path


class Arrivals:
    """Receives the played topics in the test node: (monotonic arrival time, index) per topic, and
    /clock."""

    def __init__(self, node: Node, state_topic: str = STATE) -> None:
        self.got: dict[str, list[tuple[float, int]]] = {STATE: [], INFO: [], "other": []}
        self.clock: list[int] = []
        node.create_subscription(
            PlanarState, state_topic, lambda m: self._add(STATE, m.window_samples), DEEP
        )
        node.create_subscription(
            ControllerInfo, INFO, lambda m: self._add(INFO, m.setpoint.trajectory_index), qos.INFO
        )
        node.create_subscription(
            Clock,
            "/clock",
            lambda m: self.clock.append(m.clock.sec * 10**9 + m.clock.nanosec),
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        )
        if state_topic != STATE:
            node.create_subscription(
                PlanarState, STATE, lambda m: self._add("other", m.window_samples), DEEP
            )

    def _add(self, topic: str, index: int) -> None:
        self.got[topic].append((time.monotonic(), index))


@pytest.fixture
def play() -> Iterator:
    """Run bag_player with arguments to completion (waiting for subscribers first); return its
    output."""
    procs: list[subprocess.Popen] = []

    def _play(*args: str) -> str:
        exe = find_executable("hsa_bag", "bag_player")
        proc = start_process([exe, *args, "--wait-for-subscribers", "30", "--delay", "0.5"])
        procs.append(proc)
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, out
        time.sleep(0.3)  # last deliveries
        return out

    yield _play
    for proc in procs:
        stop_process(proc)


def interarrival_errors(got: list[tuple[float, int]], period: float) -> np.ndarray:
    """|arrival gap − bag gap| [s] over consecutive received indices."""
    arr = np.array(got)
    gaps = np.diff(arr[:, 0]) - np.diff(arr[:, 1]) * period
    return np.abs(gaps)


def test_timing_and_order_across_files(ros_node: Node, bag: Path, play) -> None:
    rx = Arrivals(ros_node)
    out = play(str(bag))
    assert "published 480 messages in 1 pass(es)" in out
    info, state = rx.got[INFO], rx.got[STATE]
    assert [i for _, i in info] == list(range(80))  # reliable: all, in order
    assert len(state) >= 0.97 * 400 and [i for _, i in state] == sorted(i for _, i in state)
    errors = [interarrival_errors(state, 0.005), interarrival_errors(info, 0.025)]
    assert all(np.median(err) <= 5e-3 for err in errors), [np.median(err) for err in errors]
    # over ~480 gaps: robust to a single scheduling hiccup
    pooled_p99 = np.percentile(np.concatenate(errors), 99)
    assert pooled_p99 <= 50e-3, pooled_p99
    # every message on its schedule (a file-order player would be a second off for half of them)
    times = sorted([(a, i * 0.005) for a, i in state] + [(a, i * 0.025) for a, i in info])
    t0 = min(a - b for a, b in times)
    lag = np.array([a - b - t0 for a, b in times])
    assert lag.max() < 0.3, lag.max()
    assert info[-1][0] - info[0][0] == pytest.approx(79 * 0.025, abs=0.03)


def test_rate_factor_two_topic_selection_and_remap(ros_node: Node, bag: Path, play) -> None:
    rx = Arrivals(ros_node, state_topic="/replay/state")
    play(str(bag), "--rate", "2", "--topics", STATE, INFO, "--remap", f"{STATE}:=/replay/state")
    info = rx.got[INFO]
    assert [i for _, i in info] == list(range(80))
    assert info[-1][0] - info[0][0] == pytest.approx(79 * 0.025 / 2, abs=0.03)  # half the span
    # all on /replay/state, none on /hsa/state
    assert len(rx.got[STATE]) >= 0.97 * 400 and not rx.got["other"]


def test_loop_with_start_offset_and_clock_never_goes_back(ros_node: Node, bag: Path, play) -> None:
    rx = Arrivals(ros_node)
    out = play(str(bag), "--topics", INFO, "--start-offset", "1.5", "--loop", "3", "--clock", "100")
    assert "in 3 pass(es)" in out
    indices = [i for _, i in rx.got[INFO]]
    assert indices == list(range(60, 80)) * 3  # t >= 1.5 s, three passes
    # played span + mean message period
    loop_span = (SPAN - 0.005 - 1.5) + (SPAN - 0.005) / (480 - 1)
    schedule = np.array([k // 20 * loop_span + (i - 60) * 0.025 for k, i in enumerate(indices)])
    lag = np.array([a for a, _ in rx.got[INFO]]) - schedule
    assert np.ptp(lag) < 0.3  # each pass follows the previous one by loop_span: no pause, no burst
    clock = np.array(rx.clock)
    assert clock.size > 100 and np.all(np.diff(clock) >= 0)
    assert clock[0] == pytest.approx(START_NS + 1.5e9, abs=2e7)
    # to the last message
    assert clock[-1] - clock[0] == pytest.approx((2 * loop_span + 0.475) * 1e9, abs=0.05e9)


def test_wait_topics_awaits_only_the_named_subscribers(ros_node: Node, bag: Path) -> None:
    got: list[int] = []
    ros_node.create_subscription(
        ControllerInfo, INFO, lambda m: got.append(m.setpoint.trajectory_index), qos.INFO
    )
    exe = find_executable("hsa_bag", "bag_player")
    start = time.monotonic()  # /nobody has no subscriber: waiting for it would take the whole 60 s
    proc = start_process(
        [
            exe,
            str(bag),
            "--topics",
            STATE,
            INFO,
            "--remap",
            f"{STATE}:=/nobody",
            "--wait-for-subscribers",
            "60",
            "--wait-topics",
            INFO,
        ]
    )
    try:
        out, _ = proc.communicate(timeout=120)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, out
    assert time.monotonic() - start < 40.0 and "no subscriber" not in out
    time.sleep(0.3)
    assert got == list(range(80))  # the awaited subscriber had it all


def test_unknown_topic_is_refused(bag: Path, capsys) -> None:
    assert player.main([str(bag), "--topics", "/nope"]) == 2
    assert "topic /nope is not in the bag" in capsys.readouterr().err
    assert player.main([str(bag), "--remap", "/nope:=/x"]) == 2
    assert player.main([str(bag), "--topics", INFO, "--wait-topics", STATE]) == 2
    assert f"--wait-topics {STATE} is not a played topic" in capsys.readouterr().err


LOCKSTEP = ["-p", "use_sim_time:=true", "-p", "lockstep:=true"]


def lockstep_recorder(output: Path) -> subprocess.Popen:
    """A bag_recorder (/bag_recorder) in lockstep recording both played topics into ``output``."""
    proc = start_process(
        [
            find_executable("hsa_bag", "bag_recorder"),
            "--ros-args",
            "-p",
            f"output:={output}",
            "-p",
            f"topics:=[{STATE}, {INFO}]",
            *LOCKSTEP,
        ]
    )
    wait_for_line(proc, "ready", timeout=120.0)
    return proc


def lockstep_player(bag: Path, participants: str, timeout: float, *args: str) -> subprocess.Popen:
    """bag_player in lockstep with ``participants`` (a YAML list) and ``barrier_timeout``."""
    return start_process(
        [
            find_executable("hsa_bag", "bag_player"),
            str(bag),
            *args,
            "--ros-args",
            *LOCKSTEP,
            "-p",
            f"participants:={participants}",
            "-p",
            f"barrier_timeout:={timeout}",
        ]
    )


@contextmanager
def clock_watcher() -> Iterator[list[int]]:
    """A lockstep participant in the test process (/clock_watch, use_sim_time): yields the /clock
    values it takes."""
    node = rclpy.create_node(
        "clock_watch", parameter_overrides=[Parameter("use_sim_time", value=True)]
    )
    got: list[int] = []
    node.create_subscription(
        Clock,
        "/clock",
        lambda m: got.append(m.clock.sec * 10**9 + m.clock.nanosec),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
    )
    participant = lockstep.Participant(node)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop: list[int] = []
    thread = threading.Thread(
        target=runner.spin_lockstep, args=(executor, participant, stop), daemon=True
    )
    thread.start()
    try:
        yield got
    finally:
        stop.append(1)
        thread.join(timeout=5)
        executor.shutdown()
        node.destroy_node()


def test_lockstep_records_every_message_at_its_log_time(
    ros_node: Node, bag: Path, tmp_path: Path
) -> None:
    recorder = lockstep_recorder(tmp_path / "lockstep")
    try:
        with (
            clock_watcher() as clock_values
        ):  # a participant: time starts only once its /clock is matched
            player_proc = lockstep_player(bag, "[/bag_recorder, /clock_watch]", 30.0)
            out, _ = player_proc.communicate(timeout=300)
            clock = np.array(clock_values)
        assert player_proc.returncode == 0, out
        assert (
            "published 480 messages in 1 pass(es)" in out
            and "lockstep: simulated time starts" in out
        ), out
    finally:
        assert stop_process(recorder) == 0
    with Bag(bag) as original, Bag(tmp_path / "lockstep") as recorded:
        played = sorted((t, topic, data) for topic, t, data in original.messages([STATE, INFO]))
        got = sorted((t, topic, data) for topic, t, data in recorded.messages([STATE, INFO]))
    # every message (the 200 Hz stream is best effort), each logged at its recorded log time
    assert got == played
    # /clock, as a participant sees it: in order, only log times, from the first to the last (a
    # depth-1 reliable writer may replace a value a busy reader has not taken yet, so not
    # necessarily every one)
    log_times = {t for t, _, _ in played}
    assert clock.size and np.all(np.diff(clock) >= 0) and set(clock) <= log_times, clock
    assert clock[0] == played[0][0] and clock[-1] == played[-1][0]


def test_lockstep_participant_that_stalls_fails_the_player_naming_it(
    bag: Path, tmp_path: Path
) -> None:
    recorder = lockstep_recorder(tmp_path / "stalled")
    player_proc = lockstep_player(bag, "[/bag_recorder]", 2.0, "--loop")
    try:
        wait_for_line(player_proc, "lockstep: simulated time starts", timeout=120.0)
        os.kill(recorder.pid, signal.SIGSTOP)  # the participant stops answering mid-run
        stopped = time.monotonic()
        out, _ = player_proc.communicate(timeout=60)
        took = time.monotonic() - stopped
    finally:
        os.kill(recorder.pid, signal.SIGCONT)
        stop_process(player_proc)
        stop_process(recorder)
    assert player_proc.returncode == 1, out
    assert "[ERROR]" in out and "not finished after" in out and "/bag_recorder" in out, out
    assert 2.0 <= took < 30.0, took  # the barrier timeout, plus the player's own exit
    print(f"stalled participant: player exited 1 after {took:.2f} s (barrier_timeout 2 s)")


def test_lockstep_missing_participant_fails_the_start(bag: Path) -> None:
    proc = lockstep_player(bag, "[/hsa/nobody]", 0.3)
    try:
        out, _ = proc.communicate(timeout=120)
    finally:
        stop_process(proc)
    assert proc.returncode == 1, out
    assert "lockstep barrier before simulated time started not finished after" in out, out
    assert "waiting for participants ['/hsa/nobody']" in out and "published 0 messages" in out, out


def test_progress_goes_through_the_node_logger(bag: Path) -> None:
    """ready, playing and published are logger lines on stderr (what ros2 launch shows); nothing is
    printed to stdout, which ros2 launch sends to the log file only."""
    exe = find_executable("hsa_bag", "bag_player")
    done = subprocess.run(
        [exe, str(bag), "--topics", INFO, "--rate", "4"],
        env=rosenv.ros_environment(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == ""
    lines = [line for line in done.stderr.splitlines() if "[bag_player]: " in line]
    assert [line.split("]: ", 1)[1].split(" ")[0] for line in lines] == [
        "ready",
        "playing",
        "published",
    ], done.stderr
    assert "[INFO]" in lines[0] and "published 80 messages in 1 pass(es)" in lines[2], done.stderr


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGQUIT])
def test_a_closed_terminal_stops_the_player_like_ctrl_c(bag: Path, sig: signal.Signals) -> None:
    """SIGHUP (terminal or ssh session closed) and SIGQUIT (Ctrl-\\) stop the player cleanly, exit
    0, as every node; before, SIGHUP killed it and SIGQUIT dumped core."""
    exe = find_executable("hsa_bag", "bag_player")
    # 80 messages over minutes
    proc = start_process([exe, str(bag), "--topics", INFO, "--rate", "0.05"])
    try:
        wait_for_line(proc, "playing ")
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=30)
    finally:
        stop_process(proc)
    assert proc.returncode == 0, out
    assert "published " in out, out

"""Benchmark of bag record and replay: recorder throughput through DDS and replay timing error.

Writes benchmarks/results/bag.json. A synthetic bag holds the run's two main streams: 200 Hz
hsa_msgs/PlanarState (offered best effort, as the kinematics node publishes it) and 40 Hz
hsa_msgs/ControllerInfo (reliable), fully populated, ``--seconds`` long.

* **Replay timing**: bag_player plays the bag at rate 1 into a subscriber in this process; per
  topic, the error of each inter-arrival time against the bag's inter-message time (median, p99, max
  in ms), the whole-span error, and the largest lag of a message behind its schedule.
* **Record throughput**: bag_recorder records both topics while bag_player publishes the bag at rate
  factors 1 (the nominal 240 msg/s), 5 and 20. Per factor: messages published and recorded, recorded
  msgs/s and MB/s (message bytes over the recorded receive-time span), bag size, and the recorder's
  CPU time (utime + stime from /proc, from its 'ready' to the end of the replay, so including its
  idle timers) per recorded message.

The machine has 2 cores shared with other work: the 1-minute load average is recorded at start and
end. Usage: .venv/bin/python benchmarks/bench_bag.py [--seconds S]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from hsa_common import rosenv
from hsa_core.jaxsetup import configure_jax

RESULTS = Path(__file__).resolve().parent / "results" / "bag.json"
BIN = Path(sys.executable).parent
STATE, INFO = "/hsa/state", "/hsa/controller_info"
PERIODS = {STATE: 5_000_000, INFO: 25_000_000}  # ns
RATE_FACTORS = (1.0, 5.0, 20.0)


def make_bag(path: Path, seconds: float) -> dict[str, int]:
    """Write the synthetic bag (index in PlanarState.window_samples /
    ControllerInfo.setpoint.trajectory_index)."""
    from rclpy.serialization import serialize_message
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    from hsa_bag.msgtypes import TypeRegistry
    from hsa_bag.storage import SplitBagWriter
    from hsa_msgs.msg import ControllerInfo, PlanarState

    infinite = QosTime(9223372036, 854775807)

    def offer(reliability: QosReliability) -> Qos:
        return Qos(
            QosHistory.UNKNOWN,
            0,
            reliability,
            QosDurability.VOLATILE,
            infinite,
            infinite,
            QosLiveliness.AUTOMATIC,
            infinite,
            False,
        )

    registry = TypeRegistry()
    for msgtype in ("hsa_msgs/msg/PlanarState", "hsa_msgs/msg/ControllerInfo"):
        registry.ensure(msgtype)
    writer = SplitBagWriter(path, registry.store)
    writer.open()
    handles = {
        STATE: writer.add_topic(
            STATE, "hsa_msgs/msg/PlanarState", [offer(QosReliability.BEST_EFFORT)]
        ),
        INFO: writer.add_topic(
            INFO, "hsa_msgs/msg/ControllerInfo", [offer(QosReliability.RELIABLE)]
        ),
    }
    t0 = time.time_ns()
    events = []
    for topic, period in PERIODS.items():
        for i in range(round(seconds * 1e9 / period)):
            events.append((t0 + i * period, topic, i))
    rng = np.random.default_rng(0)
    sizes = {STATE: 0, INFO: 0}
    for t, topic, i in sorted(events):
        stamp = (t // 10**9, t % 10**9)
        if topic == STATE:
            msg = PlanarState(window_samples=i, velocity_valid=True)
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
            msg.header.frame_id = "hsa_base"
            msg.q.kappa_be, msg.q.sigma_sh, msg.q.sigma_ax = rng.normal(size=3).tolist()
        else:
            msg = ControllerInfo(
                controller="psatid", state=ControllerInfo.STATE_TRACKING, saturated=bool(i % 7 == 0)
            )
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
            msg.setpoint.trajectory_index = i
            msg.varphi, msg.varphi_des, msg.e_int = (
                rng.normal(size=3),
                rng.normal(size=3),
                rng.normal(size=2),
            )
            msg.phi_des_unsat, msg.phi_des_sat = rng.normal(size=2), rng.random(2)
            msg.motor_goal_angles = rng.normal(size=4)
        data = serialize_message(msg)
        sizes[topic] = len(data)
        writer.write(handles[topic], t, data)
    writer.close()
    return sizes


def play(bag: Path, *args: str) -> tuple[float, int]:
    """Run bag_player to completion; return (player wall time [s], messages published) from its
    summary line."""
    proc = subprocess.run(
        [
            str(BIN / "bag_player"),
            str(bag),
            "--wait-for-subscribers",
            "30",
            "--delay",
            "0.5",
            *args,
        ],
        env=rosenv.ros_environment(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    # its logger
    match = re.search(r"published (\d+) messages in \d+ pass\(es\), ([\d.]+) s", proc.stderr)
    if proc.returncode != 0 or match is None:
        raise RuntimeError(f"bag_player failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return float(match.group(2)), int(match.group(1))


def stats_ms(values: np.ndarray) -> dict[str, float]:
    """Median, p99 and max of |values| [s] in ms."""
    values = np.abs(values)
    return {
        "median_ms": round(float(np.median(values)) * 1e3, 3),
        "p99_ms": round(float(np.percentile(values, 99)) * 1e3, 3),
        "max_ms": round(float(values.max()) * 1e3, 3),
    }


def replay_timing(bag: Path, seconds: float) -> dict[str, object]:
    """Inter-arrival and schedule errors of a rate-1 replay received in this process."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from hsa_common import qos
    from hsa_msgs.msg import ControllerInfo, PlanarState

    rclpy.init()
    node = rclpy.create_node("bench_bag_receiver")
    got: dict[str, list[tuple[float, int]]] = {STATE: [], INFO: []}
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    node.create_subscription(
        PlanarState, STATE, lambda m: got[STATE].append((time.monotonic(), m.window_samples)), deep
    )
    node.create_subscription(
        ControllerInfo,
        INFO,
        lambda m: got[INFO].append((time.monotonic(), m.setpoint.trajectory_index)),
        qos.INFO,
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        play(bag)
        time.sleep(0.5)
    finally:
        executor.shutdown()
        spinner.join(timeout=5)
        node.destroy_node()
        rclpy.try_shutdown()
    result: dict[str, object] = {}
    schedule = []
    for topic, period in PERIODS.items():
        arr = np.array(got[topic], dtype=np.float64)
        expected = round(seconds * 1e9 / period)
        gaps = np.diff(arr[:, 0]) - np.diff(arr[:, 1]) * period * 1e-9
        span_error = (arr[-1, 0] - arr[0, 0]) - (arr[-1, 1] - arr[0, 1]) * period * 1e-9
        result[topic] = {
            "received": int(arr.shape[0]),
            "expected": expected,
            **stats_ms(gaps),
            "span_error_ms": round(span_error * 1e3, 3),
        }
        schedule += [(a, i * period * 1e-9) for a, i in arr]
    lag = np.array([a - b for a, b in schedule])
    result["schedule_lag_max_ms"] = round(float((lag - lag.min()).max()) * 1e3, 3)
    return result


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process [s]."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def record_throughput(
    bag: Path, work: Path, factor: float, sizes: dict[str, int]
) -> dict[str, object]:
    """Record both topics while the bag is played at ``factor``; counts, rates and recorder CPU."""
    from hsa_bag.bagio import Bag

    out = work / f"recorded_x{factor:g}"
    recorder = subprocess.Popen(
        [
            str(BIN / "bag_recorder"),
            "--ros-args",
            "-p",
            f"output:={out}",
            "-p",
            f"topics:=[{STATE}, {INFO}]",
        ],
        env=rosenv.ros_environment(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    assert recorder.stdout is not None
    for line in recorder.stdout:
        if "ready" in line:
            break
    cpu0 = cpu_seconds(recorder.pid)
    elapsed, published = play(bag, "--rate", str(factor))
    time.sleep(1.0)
    cpu = cpu_seconds(recorder.pid) - cpu0
    recorder.send_signal(2)
    recorder.communicate(timeout=60)
    with Bag(out) as recorded:
        counts = {t: recorded.topics[t].count if t in recorded.topics else 0 for t in (STATE, INFO)}
        span = (recorded.end - recorded.start) * 1e-9
    total = sum(counts.values())
    payload = sum(counts[t] * sizes[t] for t in counts)
    return {
        "rate_factor": factor,
        "published": published,
        "published_per_s": round(published / elapsed, 1),
        "recorded": counts,
        "recorded_fraction": round(total / published, 4),
        "recorded_msgs_per_s": round(total / span, 1),
        "recorded_MB_per_s": round(payload / span / 1e6, 3),
        "bag_bytes": sum(p.stat().st_size for p in out.iterdir()),
        "recorder_cpu_us_per_msg": round(cpu / total * 1e6, 1),
    }


def main() -> None:
    """Run both benchmarks and write the JSON results."""
    configure_jax()
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the synthetic bag")
    seconds = parser.parse_args().seconds
    rosenv.apply()
    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        bag = work / "synthetic"
        sizes = make_bag(bag, seconds)
        timing = replay_timing(bag, seconds)
        throughput = [record_throughput(bag, work, factor, sizes) for factor in RATE_FACTORS]
    results = {
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "loadavg_1min_at_start": round(load_start, 2),
            "loadavg_1min_at_end": round(os.getloadavg()[0], 2),
        },
        "bag": {"seconds": seconds, "rates_hz": {STATE: 200, INFO: 40}, "message_bytes": sizes},
        "replay_timing_rate_1": timing,
        "record_throughput": throughput,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()

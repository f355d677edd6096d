"""Setpoint flood benchmark (issue 22, item 1): does controller_node keep its 40 Hz tick under 1 000
setpoints/s?

A real controller_node process (FPU, P-satI-D, 40 Hz, no driver in the graph: ``driver_timeout:=0``,
every thread under SCHED_RR at ``--realtime-priority``, 0 = normal scheduling) is fed a ready state
at 200 Hz and the FPU worked-example setpoint by this process; once it tracks, this process
publishes valid setpoints (each with its own index and stamp) at ``--rate`` per second for
``--seconds`` on its ``setpoint`` topic. The tick times are the header stamps of ``controller_info``
(one per tick, the node clock = the wall clock); the figures over the flood window: tick rate,
longest gap between two ticks, ticks not tracking, /diagnostics reports per second, the CPU time the
controller process used per second of the window (/proc: the flood's cost, which the machine's load
does not change much, unlike the tick figures), the controller's setpoint counters (received,
activated, superseded, rejected) and its scheduling from its last report. Each scenario runs quiet
and beside two ``python3 -c "while 1: pass"`` processes (started and killed by PID here, in this
process's session; the controller has a session of its own), and the same window without a flood
beside the two processes is the control: what the machine's load alone does to the tick. This
process is not real-time. The machine's load average is recorded: on a shared machine the "quiet"
runs are not quiet. Writes benchmarks/results/setpoint_flood.json (``--baseline FILE`` embeds an
earlier result, e.g. of the code before the fix run with that checkout's interpreter, or of
``--realtime-priority 0``).

    .venv/bin/python benchmarks/bench_setpoint_flood.py [--rate 1000] [--seconds 10]
        [--realtime-priority 10] [--out FILE] [--baseline FILE] [--label LABEL]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message

from hsa_common import qos, rosenv
from hsa_common.launcher import find_executable
from hsa_msgs.msg import ControllerInfo, PlanarState, Setpoint

ROOT = Path(__file__).resolve().parents[1]
NS = "/flood"
CONTROL = "controller_node: control loop"
COUNTERS = (
    "received_setpoints",
    "setpoints",
    "superseded_setpoints",
    "rejected_setpoints",
    "pending_setpoints",
    "deadline_misses",
    "stale_events",
    "stale_stops",
    "driver_lost_events",
)
TARGETS = {"tick_rate_hz_min": 39.0, "longest_gap_ms_max": 50.0}


@contextmanager
def burners(n: int) -> Iterator[list[int]]:
    """n processes that keep one core each busy; killed by PID at the end."""
    procs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
            p.wait()


def worked_example() -> Setpoint:
    """The FPU worked example of planning_and_control.md §2.2 (exact model)."""
    msg = Setpoint(phi_ss=np.array([1.9846028, 1.6323408]), optimality_error=1e-16)
    msg.header.frame_id = "hsa_base"
    msg.chiee_des.x, msg.chiee_des.y, msg.chiee_des.theta = 0.00479247, 0.12781018, -0.066980133
    msg.q_des.kappa_be, msg.q_des.sigma_sh, msg.q_des.sigma_ax = (
        -1.1352565,
        0.0080816386,
        0.30410104,
    )
    return msg


class Bench:
    """This process's ROS side: state feeder, setpoint publisher, controller_info and /diagnostics
    recorders."""

    def __init__(self) -> None:
        self.node = rclpy.create_node("setpoint_flood_bench")
        self.sp_pub = self.node.create_publisher(Setpoint, f"{NS}/setpoint", qos.LATCHED)
        self.state_pub = self.node.create_publisher(PlanarState, f"{NS}/state", qos.SENSOR)
        self.infos: list[tuple[float, bytes]] = []  # (arrival, raw) of controller_info
        self.reports: list[
            tuple[float, dict[str, str]]
        ] = []  # (arrival, values) of the control loop's status
        self.node.create_subscription(
            ControllerInfo,
            f"{NS}/controller_info",
            lambda raw: self.infos.append((time.monotonic(), raw)),
            500,
            raw=True,
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 100)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self.executor.spin, daemon=True),
            threading.Thread(target=self._feed, daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == CONTROL:
                self.reports.append((time.monotonic(), {kv.key: kv.value for kv in status.values}))

    def _feed(self) -> None:
        """A ready state near the setpoint at 200 Hz, stamped now."""
        msg = PlanarState(velocity_valid=True, window_samples=21)
        msg.header.frame_id = "hsa_base"
        msg.chiee.x, msg.chiee.y, msg.chiee.theta = 0.0045, 0.1275, -0.066
        msg.q.kappa_be, msg.q.sigma_sh, msg.q.sigma_ax = -1.12, 0.008, 0.303
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += 0.005
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.state_pub.publish(msg)
            time.sleep(max(0.0, next_t - time.monotonic()))

    def tracking(self, timeout: float = 120.0) -> bool:
        """Wait until the controller tracks."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(
                deserialize_message(raw, ControllerInfo).state == ControllerInfo.STATE_TRACKING
                for _, raw in self.infos[-5:]
            ):
                return True
            time.sleep(0.1)
        return False

    def flood(self, rate: float, seconds: float) -> tuple[float, float, int]:
        """Publish valid setpoints at ``rate`` for ``seconds``; returns the window (monotonic) and
        the count sent."""
        n = int(rate * seconds)
        msg = worked_example()
        msg.trajectory_length = n
        t0 = time.monotonic()
        for k in range(n):
            msg.trajectory_index = k
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.sp_pub.publish(msg)
            time.sleep(max(0.0, t0 + (k + 1) / rate - time.monotonic()))
        return t0, time.monotonic(), n

    def close(self) -> None:
        self._stop.set()
        self.executor.shutdown()
        self.node.destroy_node()


def cpu_s(pid: int) -> float:
    """User + system CPU time [s] of process pid so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def scenario(
    bench: Bench, rate: float, seconds: float, n_burners: int, pid: int
) -> dict[str, object]:
    """One flood (none with rate 0), quiet or beside n_burners busy processes: the tick figures over
    its window."""
    with burners(n_burners) as pids:
        time.sleep(1.0)
        load = os.getloadavg()[0]
        before = bench.reports[-1][1] if bench.reports else {}
        n_infos, n_reports = len(bench.infos), len(bench.reports)
        cpu0 = cpu_s(pid)
        if rate > 0.0:
            t0, t1, sent = bench.flood(rate, seconds)
        else:
            t0, sent = time.monotonic(), 0
            time.sleep(seconds)
            t1 = time.monotonic()
        cpu1 = cpu_s(pid)
        time.sleep(2.0)  # the last reports
    infos = [
        (arrival, deserialize_message(raw, ControllerInfo))
        for arrival, raw in bench.infos[n_infos:]
    ]
    window = [m for arrival, m in infos if t0 <= arrival <= t1]
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in window])
    gaps = np.diff(stamps) if len(stamps) > 1 else np.array([np.nan])
    reports = [(arrival, values) for arrival, values in bench.reports[n_reports:]]
    in_window = [values for arrival, values in reports if t0 <= arrival <= t1]
    after = reports[-1][1] if reports else {}
    newest = infos[-1][1].setpoint if infos else None
    return {
        "burners": n_burners,
        "burner_pids": pids,
        "load_average_1min_at_start": round(load, 2),
        "setpoints_sent": sent,
        "flood_s": round(t1 - t0, 3),
        "setpoints_per_s": round(sent / (t1 - t0), 1),
        "controller_cpu_s_per_s": round((cpu1 - cpu0) / (t1 - t0), 3),
        "ticks": len(window),
        "tick_rate_hz": round((len(stamps) - 1) / (stamps[-1] - stamps[0]), 2)
        if len(stamps) > 1
        else 0.0,
        "longest_gap_ms": round(1e3 * float(np.max(gaps)), 1),
        "gap_p99_ms": round(1e3 * float(np.percentile(gaps, 99)), 1),
        "ticks_not_tracking": sum(m.state != ControllerInfo.STATE_TRACKING for m in window),
        "diagnostics_reports_per_s": round(len(in_window) / (t1 - t0), 2),
        "tick_rate_reported_hz": [values.get("tick rate [Hz]") for values in in_window],
        "counters_delta": {
            k: int(after[k]) - int(before.get(k, 0)) for k in COUNTERS if k in after
        },
        "newest_setpoint_tracked": bool(newest is not None and newest.trajectory_index == sent - 1)
        if sent
        else None,
        "scheduling": after.get("scheduling"),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=1000.0, help="setpoints per second")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=10,
        help="controller_node's realtime_priority (SCHED_RR; 0 = normal)",
    )
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "setpoint_flood.json"
    )
    parser.add_argument(
        "--baseline", type=Path, help="an earlier result to embed (e.g. the code before the fix)"
    )
    parser.add_argument("--label", default="this checkout")
    args = parser.parse_args()
    rosenv.apply()
    controller = subprocess.Popen(
        [
            find_executable("hsa_controller_node", "controller_node"),
            "--ros-args",
            "-r",
            f"__ns:={NS}",
            "-p",
            "driver_timeout:=0.0",
            "-p",
            "diagnostics_period:=1.0",
            "-p",
            "rejection_log_period:=5.0",
            "-p",
            f"realtime_priority:={args.realtime_priority}",
        ],
        env=rosenv.ros_environment(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    rclpy.init()
    bench = Bench()
    result: dict[str, object] = {
        "label": args.label,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_avg_at_start": os.getloadavg(),
            "note": "2-core VM shared with other sessions' work: 'quiet' is not idle",
        },
        "targets": TARGETS,
        "method": __doc__.split("\n\n")[1],
        "realtime_priority": args.realtime_priority,
    }
    try:
        bench.sp_pub.publish(worked_example())
        if not bench.tracking():
            raise RuntimeError("controller_node never tracked")
        time.sleep(2.0)
        result["quiet"] = scenario(bench, args.rate, args.seconds, 0, controller.pid)
        result["two_busy_processes"] = scenario(bench, args.rate, args.seconds, 2, controller.pid)
        result["two_busy_processes_no_flood"] = scenario(
            bench, 0.0, args.seconds, 2, controller.pid
        )
    finally:
        bench.close()
        rclpy.shutdown()
        controller.terminate()
        controller.wait(timeout=30)
    result["machine"]["load_avg_at_end"] = os.getloadavg()
    if args.baseline is not None:
        result["baseline"] = json.loads(args.baseline.read_text())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "baseline"}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Live-graph benchmark: the sim launch graph (wall clock) on a short FPU step schedule at 40 Hz and
200 Hz control.

Measured from the recorded bag and from the processes while they run:
* latency: mocap sample stamp → the sync write of the goal it produced leaving the driver
  (``motor_goal_stamp``: header.stamp = after the write, source_stamp = the mocap stamp), p50/p99;
  it includes the age of the newest state when the controller's timer fires (up to one mocap period
  plus transport);
* compute path: controller tick (phi_cmd header stamp) → that goal leaving the driver, p50/p99;
* controller loop: tick period jitter (controller_info header stamps) and deadline misses (a tick
  later than 1.5 nominal periods after the previous one), over the ticks while tracking;
* stage ages: the recorder's receive time minus the mocap stamp for the pose, ee_pose and state
  streams (an upper bound of each stage's output time: it includes the recorder's own delivery
  delay), p50/p99;
* CPU per node (psutil, user+system over the tracking window, in % of one core). With ``--repeat N``
  every rate runs N times; the headline figures are per-key medians, the runs are kept under
``runs`` (this 2-core VM varies from run to run). Writes benchmarks/results/graph.json. Targets
(node-suite issue): latency p99 ≤ 5 ms; < 1 % deadline misses at 200 Hz with the whole graph on 2
cores.

    .venv/bin/python benchmarks/bench_graph.py [--steps 3] [--step-period 5] [--repeat 1] [--rates
    40 200]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
import yaml
from rosbags.rosbag2 import Reader

from hsa_bag.msgtypes import TypeRegistry
from hsa_common import rosenv
from hsa_core.jaxsetup import configure_jax
from hsa_core.task.trajectories import step_reference

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "launch_scripts" / "sim.launch.yaml"
STAGES = ("/mocap/platform/pose", "/hsa/ee_pose", "/hsa/state")


def run_graph(
    rate: float, steps: int, step_period: float, work: Path
) -> tuple[Path, dict[str, float]]:
    """Run the graph once; return its bag and the CPU use per node [% of one core] while the
    sequencer ran."""
    bag = work / f"bag_{int(rate)}hz"
    config = work / f"sequencer_{int(rate)}.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "/**": {
                    "ros__parameters": {
                        "trajectory": "steps",
                        "points": [float(v) for v in step_reference("fpu").p_des[:steps].ravel()],
                        "exit_on_finish": True,
                        "finish_hold": 1.0,
                    }
                }
            }
        )
    )
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hsa_common.launcher",
            str(GRAPH),
            f"rate:={rate}",
            f"bag_dir:={bag}",
            f"setpoint_rate:={1.0 / step_period}",
            f"sequencer_config:={config}",
            "clock:=wall",
        ],
        env=rosenv.ros_environment(),
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    cpu: dict[str, float] = {}
    start: dict[int, tuple[str, psutil.Process, float]] = {}
    t_start = 0.0
    assert proc.stdout is not None
    for line in proc.stdout:
        if not start and "[hsa.controller_node]" in line and "-> tracking" in line:
            # CPU window: from the first controller output to the end of the schedule
            t_start = time.monotonic()
            for child in psutil.Process(proc.pid).children():
                times = child.cpu_times()
                start[child.pid] = (Path(child.cmdline()[1]).name, child, times.user + times.system)
        if start and "[hsa.setpoint_sequencer]" in line and "finished" in line and not cpu:
            span = time.monotonic() - t_start
            for name, child, used in start.values():
                times = child.cpu_times()
                cpu[name] = round(100.0 * (times.user + times.system - used) / span, 1)
    proc.wait(timeout=120)
    if proc.returncode != 0:
        os.killpg(proc.pid, signal.SIGKILL)
        raise RuntimeError(f"graph at {rate} Hz exited with {proc.returncode}")
    return bag, cpu


def analyse(bag: Path, rate: float) -> dict[str, float]:
    """Latency and loop-timing statistics from a recorded bag."""
    registry = TypeRegistry()
    registry.ensure("hsa_msgs/msg/ControllerInfo")
    registry.ensure("hsa_msgs/msg/PlanarActuation")
    registry.ensure("hsa_msgs/msg/PlanarPoseStamped")
    registry.ensure("hsa_msgs/msg/PlanarState")
    registry.ensure("geometry_msgs/msg/PoseStamped")
    store = registry.store
    sec = lambda t: t.sec + t.nanosec * 1e-9  # noqa: E731
    latency, ticks, writes, tick_of_source = [], [], [], {}
    stages: dict[str, list[float]] = {topic: [] for topic in STAGES}
    with Reader(bag) as reader:
        for conn, received, raw in reader.messages():
            if conn.topic in stages:
                msg = store.deserialize_cdr(raw, conn.msgtype)
                stages[conn.topic].append(received * 1e-9 - sec(msg.header.stamp))
            elif conn.topic == "/hsa/motor_goal_stamp":
                msg = store.deserialize_cdr(raw, conn.msgtype)
                if sec(msg.source_stamp) > 0:
                    latency.append(sec(msg.header.stamp) - sec(msg.source_stamp))
                    writes.append((sec(msg.source_stamp), sec(msg.header.stamp)))
            elif conn.topic == "/hsa/phi_cmd":
                msg = store.deserialize_cdr(raw, conn.msgtype)
                tick_of_source[sec(msg.source_stamp)] = sec(msg.header.stamp)
            elif conn.topic == "/hsa/controller_info":
                msg = store.deserialize_cdr(raw, conn.msgtype)
                if msg.state == 2:  # STATE_TRACKING
                    ticks.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    periods = np.diff(np.asarray(ticks))
    nominal = 1.0 / rate
    lat = np.asarray(latency) * 1e3
    compute = np.asarray([w - tick_of_source[s] for s, w in writes if s in tick_of_source]) * 1e3
    return {
        "tick_to_write_ms_p50": round(float(np.percentile(compute, 50)), 3),
        "tick_to_write_ms_p99": round(float(np.percentile(compute, 99)), 3),
        "latency_ms_p50": round(float(np.percentile(lat, 50)), 3),
        "latency_ms_p99": round(float(np.percentile(lat, 99)), 3),
        "latency_samples": int(lat.size),
        "ticks": int(len(ticks)),
        "period_ms_mean": round(float(periods.mean() * 1e3), 3),
        "period_jitter_ms_std": round(float(periods.std() * 1e3), 3),
        "period_dev_ms_p99": round(float(np.percentile(np.abs(periods - nominal), 99) * 1e3), 3),
        "deadline_misses": int(np.sum(periods > 1.5 * nominal)),
        "deadline_miss_fraction": round(float(np.mean(periods > 1.5 * nominal)), 4),
        **{
            f"recorder_rx_minus_mocap_stamp_ms_p50_p99 {topic}": [
                round(float(np.percentile(ages, p) * 1e3), 3) for p in (50, 99)
            ]
            for topic, ages in stages.items()
        },
    }


def median_of(runs: list[dict]) -> dict:
    """Per-key median over runs (nested dicts, e.g. CPU per node, key by key; lists
    element-wise)."""
    first = runs[0]
    out: dict = {}
    for key, value in first.items():
        if isinstance(value, dict):
            out[key] = median_of([r[key] for r in runs])
        else:
            out[key] = np.round(np.median([r[key] for r in runs], axis=0), 4).tolist()
    return out


def main() -> int:
    """Run both rates, print and write the JSON."""
    configure_jax()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--step-period", type=float, default=5.0)
    parser.add_argument(
        "--repeat", type=int, default=1, help="runs per rate; the headline figures are medians"
    )
    parser.add_argument("--rates", type=float, nargs="+", default=[40.0, 200.0])
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "graph.json")
    args = parser.parse_args()
    rosenv.apply()
    results: dict[str, object] = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "executor": os.environ.get("HSA_EXECUTOR", "events"),
            "load_avg_at_start": os.getloadavg(),
        },
        "targets": {"latency_ms_p99": 5.0, "deadline_miss_fraction_200hz": 0.01},
        "method": __doc__.split("\n\n")[1],
    }
    for rate in args.rates:
        runs = []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as tmp:
                bag, cpu = run_graph(rate, args.steps, args.step_period, Path(tmp))
                runs.append({**analyse(bag, rate), "cpu_percent_of_one_core": cpu})
        results[f"{int(rate)}hz"] = {**median_of(runs), "runs": runs}
    results["machine"]["load_avg_at_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Lockstep benchmark (issue "one simulated world"): determinism under load, speed, and the recorder
on the wall clock.

* **Determinism:** the main job (``launch_scripts/run_sim_experiment.py``, FPU steps, P-satI-D,
  lockstep) twice, the second time beside two CPU-burning processes; a SHA-256 digest of the
  concatenated serialized payloads per recorded topic. Every topic must agree except the documented
  wall-clock-only ones (``/diagnostics``: CPU and rate figures; ``/hsa/controller_info`` carries
  ``compute_time``, so it is compared with that field zeroed). The log times are compared too (their
  own digest per topic).
* **Speed:** graph wall time of the runs (start of the graph to its end, as run.sh prints it), at 40
  Hz, and of a run at 200 Hz control.
* **Recorder on the wall clock:** the sim graph with ``clock:=wall`` (11 steps at 0.3 Hz, or the
  full schedule with ``--wall-steps``) beside two busy processes; the mocap samples the recorder
  lost = samples the simulator published (one per 5 ms between the first and the last stamp) −
  samples in the bag.
* **Fidelity:** P-satI-D RMSE of the lockstep graph and of ``hsa_experiment`` (same world and seed)
  next to the paper's 4.17 mm.
Writes benchmarks/results/lockstep.json.

    .venv/bin/python benchmarks/bench_lockstep.py [--skip-200hz] [--wall-steps] [--out FILE]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hsa_bag.bagio import Bag
from hsa_bag.bagrun import runlog_from_bag
from hsa_core.analysis import metrics
from hsa_core.jaxsetup import configure_jax
from hsa_core.sim.experiment import ExperimentConfig, run_experiment

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "launch_scripts" / "run_sim_experiment.py"
WALL_ONLY = ("/diagnostics",)
PAPER_PSATID_RMSE_MM = 4.17


@contextmanager
def burners(n: int = 2):
    """n processes that keep one core each busy (the issue's load: python -c 'while 1: pass')."""
    procs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def run_graph(out: Path, *extra: str) -> dict:
    """The main job; its graph wall time [s] (start to end, as run.sh prints it) and, in lockstep,
    the wall time from the start of simulated time to its stop (sim_node's log lines) and the
    simulated time covered."""
    started = time.monotonic()
    load_before = os.getloadavg()[0]
    proc = subprocess.run(
        [sys.executable, str(RUN), "--out", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=3600,
    )
    found = re.search(r"graph finished after ([0-9.]+) s of wall time \(exit (\d+)\)", proc.stdout)
    if proc.returncode != 0 or not found:
        raise RuntimeError(
            f"run failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    result = {
        "graph_wall_s": float(found.group(1)),
        "total_wall_s": round(time.monotonic() - started, 1),
        "load_average_1min_before": round(load_before, 1),
        "load_average_1min_after": round(os.getloadavg()[0], 1),
    }
    log = (out / "graph.log").read_text(errors="replace")
    begin = re.search(r"\[(\d+\.\d+)\] \[hsa\.sim_node\]: lockstep: simulated time starts", log)
    end = re.search(
        r"\[(\d+\.\d+)\] \[hsa\.sim_node\]: lockstep: \S+ left; simulated time stops at ([0-9.]+) "
        r"s",
        log,
    )
    if begin and end:
        result["simulated_s"] = float(end.group(2))
        result["simulated_phase_wall_s"] = round(float(end.group(1)) - float(begin.group(1)), 1)
        result["real_time_factor"] = round(
            result["simulated_s"] / result["simulated_phase_wall_s"], 2
        )
    return result


def digests(bag: Path) -> dict[str, tuple[str, str]]:
    """Per topic, SHA-256 over the serialized payloads in log order (controller_info: compute_time
    zeroed) and over the log times."""
    out = {}
    with Bag(bag) as reader:
        for topic in sorted(reader.topics):
            out[topic] = _digest(reader, topic)
    return out


def _digest(reader: Bag, topic: str) -> tuple[str, str]:
    payloads, log_times = hashlib.sha256(), hashlib.sha256()
    store = reader.typestore(topic)
    msgtype = reader.topic(topic).msgtype
    for _, log_time, raw in reader.messages([topic]):
        if topic == "/hsa/controller_info":
            msg = store.deserialize_cdr(raw, msgtype)
            msg.compute_time = 0.0
            raw = store.serialize_cdr(msg, msgtype)
        payloads.update(bytes(raw))
        log_times.update(log_time.to_bytes(8, "little"))
    return payloads.hexdigest(), log_times.hexdigest()


def main() -> int:
    configure_jax()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-200hz", action="store_true")
    parser.add_argument(
        "--wall-steps",
        action="store_true",
        help="wall-clock recorder run on the full 110 s schedule (default: 3 steps of 10 s)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=ROOT / "benchmarks" / "results" / "lockstep.json",
        help="result JSON (default benchmarks/results/lockstep.json)",
    )
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_lockstep_"))
    result: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version()}}

    quiet = run_graph(work / "quiet")
    with burners():
        loaded = run_graph(work / "loaded")
    d_quiet, d_loaded = digests(work / "quiet" / "bag"), digests(work / "loaded" / "bag")
    missing = ("", "")
    compared = {
        t: {
            "quiet": d_quiet[t][0][:16],
            "loaded": d_loaded.get(t, missing)[0][:16],
            "equal": d_quiet[t][0] == d_loaded.get(t, missing)[0],
            "log_times_equal": d_quiet[t][1] == d_loaded.get(t, missing)[1],
        }
        for t in d_quiet
    }
    result["determinism"] = {
        "runs": {"quiet": quiet, "loaded_two_burners": loaded},
        "topics": compared,
        "identical_except_wall_only": all(
            v["equal"] for t, v in compared.items() if t not in WALL_ONLY
        ),
        "log_times_identical_except_wall_only": all(
            v["log_times_equal"] for t, v in compared.items() if t not in WALL_ONLY
        ),
        "wall_only_topics": list(WALL_ONLY),
    }
    result["speed"] = {"fpu_steps_40hz": quiet, "target_graph_wall_s": 35.0}
    if not args.skip_200hz:
        result["speed"]["fpu_steps_200hz"] = run_graph(work / "rate200", "--rate", "200")

    log = runlog_from_bag(work / "quiet" / "bag").trimmed(110.0)
    offline = run_experiment(ExperimentConfig("fpu", "psatid")).metrics
    graph = metrics.evaluate_run(
        log.t,
        log.chiee_des[:, :2],
        log.chiee[:, :2],
        log.saturated,
        duration=110.0,
        name=offline.name,
    )
    result["fidelity"] = {
        "psatid_rmse_mm": {
            "lockstep_graph": round(graph.rmse * 1e3, 3),
            "offline": round(offline.rmse * 1e3, 3),
            "paper": PAPER_PSATID_RMSE_MM,
        },
        "summary_tables_identical": metrics.format_summary([graph])
        == metrics.format_summary([offline]),
    }

    with burners():
        wall = run_graph(
            work / "wall",
            "--clock",
            "wall",
            *([] if args.wall_steps else ["--setpoint-rate", "0.3"]),
        )
    with Bag(work / "wall" / "bag") as reader:
        store = reader.typestore("/mocap/platform/pose")
        stamps = [
            store.deserialize_cdr(raw, "geometry_msgs/msg/PoseStamped").header.stamp
            for _, _, raw in reader.messages(["/mocap/platform/pose"])
        ]
    ns = np.array([s.sec * 10**9 + s.nanosec for s in stamps])
    published = int(round((ns.max() - ns.min()) / 5e6)) + 1
    result["wall_clock_recorder"] = {
        "load": "two busy processes",
        "graph_wall_s": wall["graph_wall_s"],
        "mocap_samples_published": published,
        "recorded": len(ns),
        "lost": published - len(np.unique(ns)),
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Lockstep speed (issue "one simulated world"): graph wall time at 40 Hz and 200 Hz, and the CPU
floor of the graph.

The target is the 110 s FPU step experiment in ≤ 35 s of graph wall time on 2 cores. This benchmark
measures what bounds it: the CPU time the graph's processes need per simulated second, on the wall
clock (the graph's own work, no barrier) and in lockstep (work plus the barrier's reports). Each is
a marginal figure: the main job (``launch_scripts/run_sim_experiment.py``) is run with the paper's
schedule (11 steps of 10 s) and with a short one (11 steps of 1 s), and CPU = user + system time of
the job and all its processes (``RUSAGE_CHILDREN``); the difference over the difference of simulated
time removes start-up (imports, JAX compilation) from the figure. On ``cores`` cores no run can take
less wall time than CPU / cores. Writes benchmarks/results/lockstep_speed.json.

    .venv/bin/python benchmarks/bench_lockstep_speed.py [--skip-200hz]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "launch_scripts" / "run_sim_experiment.py"
TARGET_S = 35.0
PAPER_SPAN_S = 110.0


def run(out: Path, *extra: str) -> dict:
    """One main job: graph wall time, simulated span and CPU seconds of the job with all its
    processes."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    proc = subprocess.run(
        [sys.executable, str(RUN), "--out", str(out), *extra],
        capture_output=True,
        text=True,
        timeout=3600,
    )
    wall = time.monotonic() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    found = re.search(r"graph finished after ([0-9.]+) s of wall time \(exit (\d+)\)", proc.stdout)
    if proc.returncode != 0 or not found:
        raise RuntimeError(
            f"run failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    log = (out / "graph.log").read_text(errors="replace")
    stamps = [
        float(t)
        for t in re.findall(
            r"^\[INFO\] \[(\d+\.\d+)\] \[hsa\.setpoint_sequencer\]: (?:service "
            r"available; first point|.*finished; exiting)",
            log,
            re.M,
        )
    ]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "graph_wall_s": float(found.group(1)),
        "total_wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "schedule_wall_s": round(stamps[-1] - stamps[0], 1) if len(stamps) == 2 else None,
        "load_average_1min_after": round(os.getloadavg()[0], 1),
    }


def marginal(full: dict, short: dict, span_full: float, span_short: float) -> float:
    """CPU seconds per simulated second, start-up removed."""
    return round((full["cpu_s"] - short["cpu_s"]) / (span_full - span_short), 3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-200hz", action="store_true")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_lockstep_speed_"))
    cores = os.cpu_count() or 1
    result: dict = {
        "machine": {"cpus": cores, "python": platform.python_version()},
        "target_graph_wall_s": TARGET_S,
    }
    short_span = 11 * 1.0  # 11 steps at 1 Hz
    for clock in ("wall", "lockstep"):
        full = run(work / f"{clock}_full", "--clock", clock)
        short = run(work / f"{clock}_short", "--clock", clock, "--setpoint-rate", "1")
        per_s = marginal(full, short, PAPER_SPAN_S, short_span)
        result[clock] = {
            "fpu_steps_40hz": full,
            "fpu_steps_40hz_1s_steps": short,
            "cpu_s_per_simulated_s": per_s,
            "wall_floor_s_for_110s": round(per_s * PAPER_SPAN_S / cores, 1),
        }
    if not args.skip_200hz:
        result["lockstep"]["fpu_steps_200hz"] = run(work / "rate200", "--rate", "200")
    result["finding"] = (
        "the graph's own work (wall clock, no barrier) needs "
        f"{result['wall']['cpu_s_per_simulated_s']} CPU s per simulated s, so 110 s cannot take "
        f"less than {result['wall']['wall_floor_s_for_110s']} s on {cores} cores even with a "
        f"barrier that costs nothing; lockstep needs {result['lockstep']['cpu_s_per_simulated_s']}"
    )
    out = ROOT / "benchmarks" / "results" / "lockstep_speed.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Torque-off latency of the whole sim graph's Ctrl-C, as a distribution (issue 6's bound: 100 ms).

tests/ros/test_shutdown_torque.py checks one Ctrl-C against the bound; this runs the same stop
``--runs`` times, beside ``--burners`` processes that keep a core busy each: the sim graph of
run.sh on the wall clock (``launch_scripts/sim.launch.yaml record:=false clock:=wall``), SIGINT to
its process group once the controller's goals reach the servos, then the time from the signal to
the emulated servos' torque-off (sim_node's report as it removes the bus, CLOCK_MONOTONIC), to the
driver's confirmation (its log line) and to the launcher's exit (with the launcher's last output
when it did not exit 0). Writes the runs and their summary under ``--key`` in
benchmarks/results/stop_latency.json (other keys are kept).

    .venv/bin/python benchmarks/bench_stop_latency.py [--runs 12] [--burners 2] [--key KEY]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import results_doc

from hsa_common.launcher import STUCK

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "launch_scripts" / "sim.launch.yaml"
BOUND_MS = 100.0
OFF = re.compile(r"bus removed with torque off on every servo \(off since monotonic ([0-9.]+) s\)")
CONFIRMED = re.compile(r"\[(\d+\.\d+)\] \[hsa\.dynamixel_driver\]: torque off \(shut down\)")
GOALS_WRITTEN = 4.0  # [s] after "torque on": the controller is tracking and its goals are written


def stop_once(workdir: Path) -> dict:
    """One start and Ctrl-C of the sim graph: latencies [ms] and the launcher's exit code."""
    launcher = subprocess.Popen(
        [sys.executable, "-m", "hsa_common.launcher", str(GRAPH), "record:=false", "clock:=wall"],
        cwd=workdir,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    lines: list[str] = []
    try:
        assert launcher.stdout is not None
        for line in launcher.stdout:
            lines.append(line)
            if "torque on" in line:
                break
        else:
            raise RuntimeError("the graph ended before torque on:\n" + "".join(lines[-40:]))
        reader = threading.Thread(target=lambda: lines.extend(launcher.stdout), daemon=True)
        reader.start()
        time.sleep(GOALS_WRITTEN)
        sent, sent_wall = time.monotonic(), time.time()
        os.killpg(launcher.pid, signal.SIGINT)
        code = launcher.wait(timeout=60.0)
        ended = time.monotonic() - sent
        reader.join(timeout=5.0)
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.wait()
    output = "".join(lines)
    off, confirmed = OFF.search(output), CONFIRMED.search(output)
    if off is None:
        raise RuntimeError("sim_node did not report torque off:\n" + output[-4000:])
    run = {
        "torque_off_ms": round((float(off.group(1)) - sent) * 1e3, 1),
        "confirmed_ms": round((float(confirmed.group(1)) - sent_wall) * 1e3, 1)
        if confirmed
        else None,
        "graph_ended_s": round(ended, 2),
        "launcher_exit": code,
    }
    if code != 0:  # which node did not end and where it was stuck, or what the launcher said last
        stuck = output.find(STUCK)
        run["output_tail"] = output[max(0, stuck - 2000) :] if stuck >= 0 else output[-6000:]
    return run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=12)
    parser.add_argument("--burners", type=int, default=2)
    parser.add_argument("--key", default="latest")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "stop_latency.json"
    )
    args = parser.parse_args()
    if args.runs < 1 or args.burners < 0:
        parser.error("--runs must be >= 1 and --burners >= 0")
    burners = [
        subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.burners)
    ]
    runs = []
    try:
        with tempfile.TemporaryDirectory(prefix="hsa_stop_") as workdir:
            for k in range(args.runs):
                runs.append(stop_once(Path(workdir)))
                print(f"run {k + 1}/{args.runs}: {runs[-1]}", flush=True)
    finally:
        for p in burners:
            p.kill()
            p.wait()
    off = [r["torque_off_ms"] for r in runs]
    result = {
        "commit": subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
        ).stdout.strip(),
        "machine": results_doc.machine(),
        "burners": args.burners,
        "bound_ms": BOUND_MS,
        "torque_off_ms": {
            "min": min(off),
            "median": statistics.median(off),
            "max": max(off),
            "over_bound": sum(v >= BOUND_MS for v in off),
        },
        "runs": runs,
    }
    doc = json.loads(args.out.read_text()) if args.out.exists() else {}
    doc[args.key] = result
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(result["torque_off_ms"]))
    failed = result["torque_off_ms"]["over_bound"] or any(r["launcher_exit"] for r in runs)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

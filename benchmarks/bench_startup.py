"""Start-up benchmark (issue "the lab's first day"): seconds from a node's start to its "ready"
line.

Every process of the sim graph (``launch_scripts/sim.launch.yaml``, wall clock, its default
parameter files), from its installed ``lib/<package>/<executable>``:

* **alone** — one node at a time, nothing else starting beside it (the sim node first and kept
  running, so the driver finds its bus and the sequencer its planner: the planner stays up too);
* **fresh** — JAX's persistent compilation cache empty (a machine that never ran the graph;
  ``HSA_JAX_CACHE_DIR`` set to a new directory). The operating system's file cache is not dropped:
  imports come from memory, as on any machine that has just installed the packages;
* **warm** — the same nodes started again with the cache the fresh starts filled (a machine that has
  run them before);
* **graph** — the whole graph started at once (all processes competing for the 2 cores), fresh and
  warm: the time until the last node is ready.

Targets: every node ready ≤ 10 s fresh and ≤ 3 s warm. Writes benchmarks/results/startup.json.

    .venv/bin/python benchmarks/bench_startup.py
"""

from __future__ import annotations

import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from hsa_common import rosenv
from hsa_common.launcher import LaunchFile

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "launch_scripts" / "sim.launch.yaml"
ARGS = {"clock": "wall", "record": "false"}
TIMEOUT = 120.0
FIRST = ("sim_node", "planner_node")  # started first and kept running: the others' peers


class Started:
    """A process whose output lines are collected with their monotonic arrival times."""

    def __init__(self, cmd: list[str], env: dict[str, str]) -> None:
        self.t0 = time.monotonic()
        self.proc = subprocess.Popen(
            cmd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        self.lines: list[tuple[float, str]] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line))

    def ready_after(self, name: str) -> float | None:
        """Seconds from start to the node's ready line, or None."""
        pattern = re.compile(rf"\[hsa\.{name}\]: ready\b")
        return next((t - self.t0 for t, line in list(self.lines) if pattern.search(line)), None)

    def wait_ready(self, names: list[str]) -> dict[str, float]:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            found = {n: self.ready_after(n) for n in names}
            if all(v is not None for v in found.values()):
                return {n: round(v, 2) for n, v in found.items()}  # type: ignore[arg-type]
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        tail = "".join(line for _, line in self.lines[-30:])
        raise RuntimeError(f"not ready within {TIMEOUT} s: {names}\n{tail}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


def environment(cache: Path) -> dict[str, str]:
    """The ROS environment of a run (localhost, run-specific domain) with its own JAX cache
    directory."""
    env = rosenv.ros_environment()
    env["HSA_JAX_CACHE_DIR"] = str(cache)
    return env


def alone(cache: Path) -> dict[str, float]:
    """Each node started by itself; seconds to ready."""
    env = environment(cache)
    procs = {p.name: p for p in LaunchFile(GRAPH, ARGS).processes()}
    times: dict[str, float] = {}
    kept: list[Started] = []
    try:
        for name in [*FIRST, *(n for n in procs if n not in FIRST)]:
            run = Started(procs[name].cmd, env)
            times.update(run.wait_ready([name]))
            if name in FIRST:
                kept.append(run)
            else:
                run.stop()
    finally:
        for run in kept:
            run.stop()
    return times


def graph(cache: Path) -> dict[str, float]:
    """The whole graph started at once by hsa_launch; seconds to each node's ready line."""
    names = [p.name for p in LaunchFile(GRAPH, ARGS).processes()]
    run = Started(
        [
            sys.executable,
            "-m",
            "hsa_common.launcher",
            str(GRAPH),
            *(f"{k}:={v}" for k, v in ARGS.items()),
        ],
        environment(cache),
    )
    try:
        return run.wait_ready(names)
    finally:
        run.stop()


def main() -> int:
    # the user's ROS_DOMAIN_ID or a reserved one, for every graph below; a bad one is refused here
    rosenv.apply()
    work = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    result: dict = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "targets_s": {"fresh": 10.0, "warm": 3.0},
        "graph_args": ARGS,
    }
    result["alone_fresh"] = alone(work / "cache_alone")
    result["alone_warm"] = alone(work / "cache_alone")
    result["graph_fresh"] = graph(work / "cache_graph")
    result["graph_warm"] = graph(work / "cache_graph")
    result["slowest"] = {
        k: max(result[k].items(), key=lambda kv: kv[1])
        for k in ("alone_fresh", "alone_warm", "graph_fresh", "graph_warm")
    }
    result["targets_met"] = {
        "fresh_alone": max(result["alone_fresh"].values()) <= 10.0,
        "warm_alone": max(result["alone_warm"].values()) <= 3.0,
        "fresh_graph": max(result["graph_fresh"].values()) <= 10.0,
        "warm_graph": max(result["graph_warm"].values()) <= 3.0,
    }
    out = ROOT / "benchmarks" / "results" / "startup.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

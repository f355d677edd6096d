"""Where the lockstep graph's time goes (issue 23, item 1): CPU and wake-ups per process, messages
per kind.

Runs the sim graph (``launch_scripts/sim.launch.yaml`` under hsa_launch, FPU steps, P-satI-D,
lockstep by default, ``--compose`` its process layout) with a short schedule (``--setpoint-rate``,
default 0.5 Hz: 11 steps of 2 s) and samples every process of the graph from /proc (user + system
CPU, voluntary and involuntary context switches of all its threads) every ``--sample`` s. Figures
per simulated second are taken between sim_node's "simulated time starts" and its "barrier traffic"
line at shutdown (which gives the simulated time reached), so start-up and the teardown do not
count. The start-up is reported apart (lockstep, ``start_up``): the wall time from the launch until
each node logs "ready" and until simulated time starts, and the CPU each process had used by its
last sample before that start. Messages per kind: every recorded topic (from the bag) and the
barrier's own traffic (sim_node's "barrier traffic" line at its shutdown: reports taken, /clock and
lead-clock messages, instants, sample runs). CPU seconds are the figures to compare on a shared
machine; wall figures carry the load they were taken at. Writes the run under ``--key`` in
benchmarks/results/lockstep_breakdown.json (``--out``; other keys are kept).

    .venv/bin/python benchmarks/bench_lockstep_breakdown.py [--setpoint-rate 0.5] [--clock lockstep]
        [--compose true|false] [--graph FILE] [--label TEXT] [--key KEY] [--out FILE]
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

from hsa_bag.bagio import Bag

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "launch_scripts" / "sim.launch.yaml"
TICK = os.sysconf("SC_CLK_TCK")


def descendants(root: int) -> list[int]:
    """PIDs of every live descendant of ``root``."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry))
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        for child in children.get(pid, []):
            found.append(child)
            todo.append(child)
    return found


def sample(pid: int) -> tuple[str, float, int, int] | None:
    """(name, CPU s, voluntary, involuntary context switches over all threads) of a process, or None
    if gone."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        voluntary = involuntary = 0
        for task in os.listdir(f"/proc/{pid}/task"):
            status = Path(f"/proc/{pid}/task/{task}/status").read_text()
            voluntary += int(re.search(r"^voluntary_ctxt_switches:\s+(\d+)", status, re.M).group(1))
            involuntary += int(
                re.search(r"^nonvoluntary_ctxt_switches:\s+(\d+)", status, re.M).group(1)
            )
    except (OSError, AttributeError):
        return None
    words = [a.decode(errors="replace") for a in argv if a]
    script = (
        next((Path(w).name for w in words[1:2] if not w.startswith("-")), Path(words[0]).name)
        if words
        else "?"
    )
    if "--ros-args" in words and "-r" in words:  # a node: its name remap, else its executable
        names = [w.split(":=", 1)[1] for w in words if w.startswith("__node:=")]
        script = names[0] if names else script
    if script == "hsa_compose":  # the composed nodes' names
        script = "+".join(w.split("=", 1)[0] for w in words[2:] if re.fullmatch(r"\w+=\S+:\w+", w))
    return script, (int(fields[11]) + int(fields[12])) / TICK, voluntary, involuntary


class Sampler:
    """Samples ``root`` and every process under it every ``period`` s into ``rows``: (monotonic,
    pid, sample)."""

    def __init__(self, root: int, period: float) -> None:
        self.rows: list[tuple[float, int, tuple[str, float, int, int]]] = []
        self._root, self._period, self._done = root, period, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._done.wait(self._period):
            now = time.monotonic()
            for pid in [self._root, *descendants(self._root)]:
                s = sample(pid)
                if s is not None:
                    self.rows.append((now, pid, s))

    def stop(self) -> None:
        self._done.set()
        self._thread.join()

    def between(self, t0: float, t1: float) -> dict[str, dict[str, float]]:
        """Per process name: CPU s and context switches between the samples nearest ``t0`` and
        ``t1``."""
        by_pid: dict[int, list[tuple[float, tuple[str, float, int, int]]]] = {}
        for t, pid, s in self.rows:
            by_pid.setdefault(pid, []).append((t, s))
        out: dict[str, dict[str, float]] = {}
        for rows in by_pid.values():
            first = min(rows, key=lambda r: abs(r[0] - t0))[1]
            last = min(rows, key=lambda r: abs(r[0] - t1))[1]
            # an exited process has no command line
            name = next((s[0] for _, s in rows if s[0] != "?"), "?")
            entry = out.setdefault(
                name, {"cpu_s": 0.0, "voluntary_switches": 0, "involuntary_switches": 0}
            )
            entry["cpu_s"] += last[1] - first[1]
            entry["voluntary_switches"] += last[2] - first[2]
            entry["involuntary_switches"] += last[3] - first[3]
        return out

    def at(self, t: float) -> dict[str, float]:
        """Per process name: the CPU s it had used by its last sample at or before ``t``."""
        last: dict[int, tuple[str, float, int, int]] = {}
        for row_t, pid, s in self.rows:
            if row_t <= t:
                last[pid] = s
        out: dict[str, float] = {}
        for s in last.values():
            out[s[0]] = out.get(s[0], 0.0) + s[1]
        return out


def start_up(
    log: str, launched: float, begin: float, offset: float, sampler: Sampler
) -> dict[str, object]:
    """Launch (``launched``, monotonic s) to simulated time (``begin``, the epoch stamp of its log
    line; ``offset``: epoch minus monotonic): wall s until each node logs "ready" and until
    ``begin``, and the CPU s each process had used by then."""
    ready = {
        node: round(float(t) - offset - launched, 2)
        for t, node in re.findall(r"\[(\d+\.\d+)\] \[hsa\.(\w+)\]: ready$", log, re.M)
    }
    cpu = sampler.at(begin - offset)
    return {
        "wall_s_until_ready_by_node": dict(sorted(ready.items(), key=lambda kv: kv[1])),
        "wall_s_until_simulated_time": round(begin - offset - launched, 2),
        "cpu_s_by_process": {k: round(v, 2) for k, v in sorted(cpu.items(), key=lambda kv: -kv[1])},
        "cpu_s_total": round(sum(cpu.values()), 2),
    }


def report_causes(log: str) -> dict[str, dict[str, int]]:
    """Per participant, its reports by cause (topics taken since the previous one, a timer, the
    clock), from the ``lockstep: reports by cause`` line each participant logs as it leaves."""
    return {
        node: json.loads(causes)
        for node, causes in re.findall(r"\[hsa\.(\w+)\]: lockstep: reports by cause (\{.*\})", log)
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setpoint-rate", default="0.5", help="[Hz] of the sequencer (11 steps)")
    parser.add_argument("--clock", choices=["lockstep", "wall"], default="lockstep")
    parser.add_argument(
        "--compose",
        choices=["true", "false"],
        help="launch argument compose (default: the graph's)",
    )
    parser.add_argument(
        "--graph", type=Path, default=GRAPH, help="launch file (a variant of sim.launch.yaml)"
    )
    parser.add_argument("--sample", type=float, default=0.5, help="[s] /proc sampling period")
    parser.add_argument(
        "--label", default="", help="what this run measures (e.g. the graph's layout)"
    )
    parser.add_argument(
        "--key", default="run", help="key of this run in the JSON (others are kept)"
    )
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "lockstep_breakdown.json"
    )
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_lockstep_breakdown_"))
    load_before = os.getloadavg()[0]
    started = time.monotonic()
    proc = subprocess.Popen(
        [
            str(Path(sys.executable).with_name("hsa_launch")),
            str(args.graph),
            f"clock:={args.clock}",
            f"setpoint_rate:={args.setpoint_rate}",
            f"bag_dir:={work / 'bag'}",
            *([f"compose:={args.compose}"] if args.compose else []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    sampler = Sampler(proc.pid, args.sample)
    log, _ = proc.communicate(timeout=3600)
    sampler.stop()
    (work / "graph.log").write_text(log)
    print(f"[bench] bag and graph log in {work}", file=sys.stderr, flush=True)
    if proc.returncode != 0:
        raise RuntimeError(f"run failed ({proc.returncode}):\n{log[-3000:]}")
    # log lines carry the wall time (epoch); the sampler's rows monotonic time: map with the offset
    # now
    offset = time.time() - time.monotonic()
    if args.clock == "lockstep":
        begin = float(
            re.search(
                r"\[(\d+\.\d+)\] \[hsa\.sim_node\]: lockstep: simulated time starts", log
            ).group(1)
        )
        found = re.search(
            r"\[(\d+\.\d+)\] \[hsa\.sim_node\]: lockstep: barrier traffic (\{.*\})", log
        )
        end, traffic = float(found.group(1)), json.loads(found.group(2))
        simulated = traffic.pop("sim_time_ns") * 1e-9
    else:
        stamps = [
            float(t)
            for t in re.findall(
                r"^\[INFO\] \[(\d+\.\d+)\] \[hsa\.setpoint_sequencer\]: (?:service "
                r"available; first point|.*finished; exiting)",
                log,
                re.M,
            )
        ]
        begin, end = stamps[0], stamps[-1]
        simulated, traffic = end - begin, {}
    per_process = sampler.between(begin - offset, end - offset)
    launch = start_up(log, started, begin, offset, sampler) if args.clock == "lockstep" else None
    with Bag(work / "bag") as reader:
        counts = {
            topic: sum(1 for _ in reader.messages([topic])) for topic in sorted(reader.topics)
        }
    per_s = {
        name: {k: round(v / simulated, 3) for k, v in entry.items()}
        for name, entry in sorted(per_process.items(), key=lambda kv: -kv[1]["cpu_s"])
    }
    total_cpu = sum(e["cpu_s"] for e in per_process.values())
    result = {
        "label": args.label,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_average_1min_before": round(load_before, 1),
            "load_average_1min_after": round(os.getloadavg()[0], 1),
            "note": (
                "shared machine: compare CPU seconds; wall figures carry the load they were taken "
                "at"
            ),
        },
        "clock": args.clock,
        "compose": args.compose,
        "setpoint_rate_hz": float(args.setpoint_rate),
        "simulated_s": round(simulated, 3),
        "simulated_phase_wall_s_loaded_machine": round(end - begin, 1),
        "total_wall_s_loaded_machine": round(time.monotonic() - started, 1),
        "cpu_s_per_simulated_s": round(total_cpu / simulated, 3),
        "per_process_per_simulated_s": per_s,
        "start_up": launch,
        "recorded_messages_per_simulated_s": {
            t: round(n / simulated, 1) for t, n in counts.items()
        },
    }
    if traffic:
        instants = max(traffic["instants"], 1)
        acks = traffic.pop("acks_by")
        result["barrier"] = {
            "per_simulated_s": {k: round(v / simulated, 1) for k, v in traffic.items()},
            "per_timer_instant": {
                k: round(v / instants, 2) for k, v in traffic.items() if k != "instants"
            },
            "reports_per_simulated_s_by_participant": {
                n: round(v / simulated, 1) for n, v in sorted(acks.items())
            },
            "wakeups_per_timer_instant": {
                n: round(e["voluntary_switches"] / instants, 1) for n, e in per_process.items()
            },
            "reports_per_timer_instant_by_cause": {
                node: {
                    cause: round(n / instants, 2)
                    for cause, n in sorted(causes.items(), key=lambda kv: -kv[1])
                }
                for node, causes in report_causes(log).items()
            },
        }
    runs = json.loads(args.out.read_text()) if args.out.exists() else {}
    runs[args.key] = result
    args.out.write_text(json.dumps(runs, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The whole test suite's time as CI sees it (issue 23: <= 15 min on 2 cores).

Clones the committed ``--ref`` (default HEAD) of this checkout into a temporary directory, runs
``./test.sh`` there as ``.ci/run`` does (bootstrap included: a fresh virtual environment from the
package cache), optionally beside ``--burners`` processes that keep a core busy each, and writes
the wall time, pytest's own time, the outcome and the ten slowest tests under ``--key`` in
benchmarks/results/suite.json (``--out``; other keys are kept). The user's package cache is not
cleared (a first run on a new machine also downloads the wheels). The JAX compilation and result
cache is the user's (``HSA_JAX_CACHE_DIR``, default ``~/.cache/hsa_ros/jax``: warm after an earlier
run on the machine, as on a CI runner that keeps its home), or with ``--cold-cache`` an empty one,
as on a new machine.

    .venv/bin/python benchmarks/bench_suite.py [--burners 2] [--cold-cache] [--key KEY] [--ref REV]
        [--out FILE]
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
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUMMARY = re.compile(r"=+ (.*) in ([\d.]+)s")
DURATION = re.compile(r"\s*[\d.]+s (call|setup|teardown) ")


def slowest(log: str, n: int = 10) -> list[str]:
    """The first ``n`` lines of pytest's "slowest durations" table (``--durations``, pytest.ini)."""
    lines = log.splitlines()
    heads = [i for i, line in enumerate(lines) if "slowest" in line and "durations" in line]
    if not heads:
        return []
    return [line.strip() for line in lines[heads[0] + 1 :] if DURATION.match(line)][:n]


def outcome(log: str) -> tuple[str, float | None]:
    """pytest's last summary line (e.g. '1130 passed, 4 warnings') and its own time [s]."""
    found = SUMMARY.findall(log)
    return (found[-1][0], float(found[-1][1])) if found else ("no pytest summary", None)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--burners", type=int, default=0, help="busy processes beside the suite")
    parser.add_argument("--ref", default="HEAD", help="the commit to clone (committed work only)")
    parser.add_argument(
        "--cold-cache", action="store_true", help="an empty JAX cache, as on a new machine"
    )
    parser.add_argument("--key", default="run", help="key of this run in the results file")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "suite.json")
    args = parser.parse_args()
    if args.burners < 0:
        parser.error(f"argument --burners: must be >= 0, got {args.burners}")
    commit = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.ref],
        capture_output=True,
        text=True,
    )
    if commit.returncode != 0:
        parser.error(f"argument --ref: not a commit of {ROOT}: {args.ref}")
    with tempfile.TemporaryDirectory(prefix="hsa_suite_") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        subprocess.run(["git", "-C", str(clone), "checkout", "-q", args.ref], check=True)
        burners = [
            subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.burners)
        ]
        env = {**os.environ, "CI": "true"}
        if args.cold_cache:
            env["HSA_JAX_CACHE_DIR"] = str(Path(tmp) / "jax_cache")
        load_before = os.getloadavg()[0]
        started = time.monotonic()
        try:
            done = subprocess.run(
                [str(clone / "test.sh")],
                cwd=clone,
                env=env,
                capture_output=True,
                text=True,
            )
        finally:
            for burner in burners:
                burner.kill()
                burner.wait()
        wall = time.monotonic() - started
    log = done.stdout + done.stderr
    summary, pytest_s = outcome(log)
    result = {
        "commit": commit.stdout.strip(),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "burners": args.burners,
        "jax_cache": "cold (empty)" if args.cold_cache else "the user's",
        "load_average_1min_before_after": [round(load_before, 1), round(os.getloadavg()[0], 1)],
        "exit_status": done.returncode,
        "outcome": summary,
        "wall_s": round(wall, 1),
        "pytest_s": pytest_s,
        "target_wall_s": 900.0,
        "slowest_tests": slowest(log),
    }
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    results[args.key] = result
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    if done.returncode != 0:
        print(log, file=sys.stderr)
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())

"""The world's calibration against the paper's four real step runs, end to end (hsa_calibrate),
with its wall time.

Runs ``hsa_core.apps.calibrate.main`` (the ``hsa_calibrate`` CLI: cross-entropy search through the
batched JAX loop, one
scan per parameter, leave-one-run-out) and writes its report with the machine and the wall time to
benchmarks/results/calibration.json (``--label NAME``: calibration_NAME.json); the figures and
the world YAML go to out/calibrate/ (out/calibrate_NAME/).

    .venv/bin/python benchmarks/bench_calibrate.py [--label NAME] [hsa_calibrate arguments]
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> int:
    from hsa_core.apps import calibrate

    label = ""
    if argv[:1] == ["--label"]:
        label, argv = f"_{argv[1]}", argv[2:]
    out = ROOT / "out" / f"calibrate{label}"
    load = os.getloadavg()[0]
    started = time.perf_counter()
    code = calibrate.main(argv + ["--out", str(out)])
    wall = time.perf_counter() - started
    report = json.loads((out / "report.json").read_text())
    doc = {
        "what": "hsa_calibrate against the reference runs (hsa_core.apps.calibrate); arguments: "
        + (" ".join(argv) or "defaults"),
        "report": report,
        "wall_s": round(wall, 1),
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "load_1min_start": load,
            "load_1min_end": os.getloadavg()[0],
        },
    }
    path = ROOT / "benchmarks" / "results" / f"calibration{label}.json"
    path.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {path} ({wall:.0f} s)")
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

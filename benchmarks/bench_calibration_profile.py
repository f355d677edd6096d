"""How well the adopted FPU world's parameters are pinned down, over many noise realizations.

``hsa_calibrate --noise-seeds 4`` scans each fitted parameter around the world it keeps with 4 mocap
noise realizations of each run; under the September command queue a run's D depends on its
realization by 0.05–0.2 mm, so those scans are rugged at the level of the 0.05 mm tolerance. This
benchmark repeats the scans around the adopted world (``config/world/fpu.yaml``) with more
realizations and a finer grid, and gives each scan point the spread of its pooled D over
realizations:

* ``D_mm``: the pooled D over every run and realization (sqrt of the mean of D²), as the fit scores
  a world;
* ``se_mm``: its standard error over realizations (the pooled D of each realization over the runs,
  their standard deviation / sqrt(N));
* ``D_mm_halves``: the pooled D over the first and the second half of the realizations, and the
  interval (pooled D within the fit's 0.05 mm tolerance of the scan's minimum) each half gives:
  where the halves disagree, the interval is set by the realizations, not by the runs.

Nothing is fitted and nothing is written to the package.
Writes benchmarks/results/calibration_profile_fpu.json.

    .venv/bin/python benchmarks/bench_calibration_profile.py [--noise-seeds N] [--points P]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import results_doc
import yaml

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise-seeds", type=int, default=16)
    parser.add_argument("--points", type=int, default=13, help="grid points per parameter")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "calibration_profile_fpu.json"
    )
    args = parser.parse_args()
    if args.noise_seeds < 2 or args.points < 2:
        parser.error("--noise-seeds and --points must be >= 2")
    from hsa_core.jaxsetup import configure_jax, use_every_core

    configure_jax()
    use_every_core()
    from hsa_core.apps import calibrate
    from hsa_core.sim.disturbance import WORLD_DIR, calibrated_world

    started = time.perf_counter()
    doc = yaml.safe_load((WORLD_DIR / "fpu.yaml").read_text())
    world = calibrated_world("fpu")
    bags = tuple(doc["runs"])
    n = args.noise_seeds
    runs = [
        calibrate.prepare_run(bag, None, dataclasses.replace(world, seed=k))
        for bag in bags
        for k in range(n)
    ]

    def d_of(worlds: list) -> np.ndarray:
        """(runs, seeds, worlds) [m]."""
        d = np.array([calibrate.deviations(r, worlds) for r in runs])
        return d.reshape(len(bags), n, len(worlds))

    def pooled_over(d: np.ndarray) -> np.ndarray:
        """sqrt(mean D²) over the leading two axes."""
        return np.sqrt(np.mean(d**2, axis=(0, 1)))

    def mm(d: np.ndarray) -> list[float | None]:
        """[m] → [mm], 4 decimals; None where the run is not finite (a diverged plant)."""
        return [round(float(v) * 1e3, 4) if np.isfinite(v) else None for v in d]

    def interval(values: np.ndarray, d: np.ndarray) -> list[float]:
        finite = np.isfinite(d)
        inside = finite & (d <= np.min(d[finite]) + calibrate.TOLERANCE)
        return [float(values[inside].min()), float(values[inside].max())]

    adopted = d_of([world])[..., 0]
    scans = {}
    for name in doc["parameters"]:
        p = calibrate.PARAMETERS[name]
        grid = p.value(np.linspace(0.0, 1.0, args.points))
        values = np.unique(np.append(grid, getattr(world, name)))
        d = d_of(calibrate.worlds_of(world, (name,), values[:, None]))
        per_seed = np.sqrt(np.mean(d**2, axis=0))  # (seeds, values)
        finite = np.isfinite(per_seed).all(axis=0)
        se = np.full(len(values), np.inf)
        se[finite] = np.std(per_seed[:, finite], axis=0, ddof=1) / np.sqrt(n)
        half = n // 2
        halves = [pooled_over(d[:, :half]), pooled_over(d[:, half:])]
        total = pooled_over(d)
        scans[name] = {
            "adopted": getattr(world, name),
            "values": values.tolist(),
            "D_mm": mm(total),
            "se_mm": mm(se),
            "interval": interval(values, total),
            "D_mm_halves": [mm(h) for h in halves],
            "interval_halves": [interval(values, h) for h in halves],
            "minimum_at": float(values[np.nanargmin(np.where(np.isfinite(total), total, np.nan))]),
        }
        print(
            f"{name}: minimum at {scans[name]['minimum_at']:.4g}, interval "
            f"{scans[name]['interval']}, halves {scans[name]['interval_halves']}",
            flush=True,
        )
    out = {
        "what": (
            "profile scans of the adopted FPU world (config/world/fpu.yaml) over many mocap noise "
            "realizations of each run (benchmarks/bench_calibration_profile.py docstring); "
            "tolerance 0.05 mm as hsa_calibrate"
        ),
        "command": "benchmarks/bench_calibration_profile.py "
        f"--noise-seeds {n} --points {args.points}",
        "runs": list(bags),
        "noise_seeds": n,
        "adopted_world": {
            "D_mm": round(float(pooled_over(adopted[..., None])[0]) * 1e3, 4),
            "D_mm_per_run_rms": {
                bag: round(float(np.sqrt(np.mean(adopted[i] ** 2))) * 1e3, 4)
                for i, bag in enumerate(bags)
            },
            "D_mm_per_run_range": {
                bag: mm(np.array([adopted[i].min(), adopted[i].max()]))
                for i, bag in enumerate(bags)
            },
        },
        "scans": scans,
        "wall_s": round(time.perf_counter() - started, 1),
    }
    results_doc.write(args.out, out)
    print(f"({out['wall_s']} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

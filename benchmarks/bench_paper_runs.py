"""What the simulator predicts for every run of the paper, each replayed with its own conditions.

For each of the paper's 28 runs (hsa_core.runs.catalogue: the four packaged reference runs and the
24 known by their conditions only) this runs the offline experiment as ``hsa_experiment --run BAG``
does (the run's profile, law, gains, σ_a,eq where known, payload and trajectory; the default world,
seed 0) and records its metrics (experiments.md §4): RMSE, response time, steady-state error,
saturation, achieved rate, plan failures. A contour run needs the authors' image (``--image-dir``);
without it the run is listed as not run. For the packaged runs the robot's RMSE from the traces is
recorded beside; for the others the spec records none, so the figures are predictions for whoever
has those runs. Writes benchmarks/results/paper_runs.json.

    .venv/bin/python benchmarks/bench_paper_runs.py [--image-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import results_doc

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image-dir", type=Path, default=None, help="the authors' assets/")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "paper_runs.json"
    )
    args = parser.parse_args()
    configure_jax()
    from hsa_core.runs import catalogue, reference
    from hsa_core.runs.catalogue import CataloguedRun
    from hsa_core.sim.experiment import replay_config, run_experiment

    rows = []
    for bag in catalogue.run_names():
        run = catalogue.replayable(bag)
        if isinstance(run, CataloguedRun):
            run = dataclasses.replace(run, image_dir=args.image_dir)
        cond = run.conditions
        row: dict[str, object] = {
            "bag": bag,
            "material": cond.material,
            "law": cond.law.value,
            "gains": dataclasses.asdict(cond.gains),
            "profile": cond.profile.name,
            "sigma_a_eq": cond.sigma_a_eq,
            "payload_kg": cond.payload,
            "trajectory": (
                "steps (real step instants)"
                if isinstance(run, reference.ReferenceRun)
                else "steps (every 10 s)"
                if run.contour is None
                else f"contour {run.contour.image}, k {run.contour.k}, r_max {run.contour.r_max}"
            ),
        }
        try:
            config = replay_config(run)
        except ValueError as err:  # a contour without its image
            rows.append(row | {"not_run": str(err)})
            print(f"{bag} not run: {err}", flush=True)
            continue
        started = time.perf_counter()
        result = run_experiment(config)
        m = result.metrics
        row |= {
            "points": len(config.reference.t),
            "duration_s": round(config.reference.duration, 3),
            "rmse_mm": round(m.rmse * 1e3, 3),
            "response_time_mean_s": round(m.response_time_mean, 3),
            "steps_not_reached": m.n_not_reached,
            "steady_state_error_mm": round(m.steady_state_error_mean * 1e3, 3),
            "saturated_fraction": round(m.saturated_fraction, 4),
            "control_rate_hz": round(m.control_rate, 2),
            "plan_failures": len(result.plan_failures),
            "wall_s": round(time.perf_counter() - started, 1),
        }
        if isinstance(run, reference.ReferenceRun):
            row["robot_rmse_mm_from_traces"] = round(run.rmse() * 1e3, 3)
        rows.append(row)
        print(
            f"{bag} {cond.material} {cond.law.value:<9} {row['trajectory']:<40} RMSE "
            f"{row['rmse_mm']:6.2f} mm  plan failures {row['plan_failures']}  ({row['wall_s']} s)",
            flush=True,
        )
    doc = {
        "what": (
            "the offline experiment replaying every run of the paper with its own conditions "
            "(hsa_experiment --run BAG: its profile, law, gains, sigma_a_eq where known, payload, "
            "trajectory), default world, seed 0; metrics of experiments.md section 4"
        ),
        "command": "benchmarks/bench_paper_runs.py"
        + (" --image-dir DIR (the authors' assets/)" if args.image_dir else ""),
        "rows": rows,
    }
    results_doc.write(args.out, doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

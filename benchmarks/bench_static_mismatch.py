"""The world's static plant/model mismatch fitted to the real robot at rest (issue 20, item 3).

The static fit is hsa_core.sysid.static_mismatch (also ``hsa_calibrate --static``): per material
every field set on its runs' end-of-step pairs (φ, pose), standard errors, leave-one-run-out, the
stiffness profile and the approach direction; the method is in that module's docstring.

* **Closed loop** (``--closed-loop``): each run replayed with its own conditions through the batched
  loop of hsa_calibrate (hsa_core.apps.calibrate.prepare_run / simulate: the PID run with the
  nominal σ_a,eq, as there) in the default world, the static fit, the FPU speed cap 3.89 rad/s that
  hsa_calibrate identified before the static fit (benchmarks/results/calibration_fpu_cmdlat.json),
  both, the leave-one-run-out static fit (with and without the cap) and the
  fit without the shear factor (with the cap); the sim-versus-real table
  (hsa_core.analysis.sim_to_real.compare) per run and world; the speed cap and the shear factor
  scanned alone in the fitted world (pooled FPU D).

Writes benchmarks/results/static_mismatch.json. The packaged static worlds
(hsa_core/hsa_core/config/world/<material>_static.yaml, read by
hsa_core.sim.disturbance.rest_world where ``adopted``) are written by ``hsa_calibrate --static
--material M --write-world`` alone.

    .venv/bin/python benchmarks/bench_static_mismatch.py [--closed-loop]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import numpy as np

from hsa_core.jaxsetup import configure_jax
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.sysid import static_mismatch
from hsa_core.sysid.static_mismatch import CHOSEN, WINDOW, world_of

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "static_mismatch.json"
DECLARED = {
    name: getattr(DisturbanceModel(), name)
    for name in ("stiffness_scale", "elongation_scale", "rest_strain_offset")
}
"""The declared world's static mismatch (``DisturbanceModel()``)."""
SERVO_CAP_FPU = json.loads(
    (ROOT / "benchmarks" / "results" / "calibration_fpu_cmdlat.json").read_text()
)["report"]["kept"]["servo_max_speed"]
"""[rad/s] the FPU speed cap hsa_calibrate identified in the declared world, before the static fit
(the world of that round's config/world/fpu.yaml)."""


def end_offsets(run, steps: tuple[int, ...]) -> np.ndarray:  # noqa: ANN001 - StepRun
    """(steps, 2) [mm] per step the mean p − p^d over its last WINDOW seconds."""
    out = []
    for _, end in run.step_bounds(steps):
        m = (run.t >= end - WINDOW) & (run.t < end)
        out.append((run.p[m] - run.p_des[m]).mean(axis=0) * 1e3)
    return np.array(out)


def closed_loop(static: dict, runs: dict[str, tuple[str, ...]]) -> dict:
    """The sim-versus-real table per run (``runs``: material → bags) in the worlds of the module
    docstring, and for FPU the speed cap scanned in the statically fitted world."""
    from hsa_core.analysis import sim_to_real
    from hsa_core.apps import calibrate
    from hsa_core.sim.disturbance import DisturbanceModel

    out: dict = {"runs": {}}
    cap = {"servo_max_speed": SERVO_CAP_FPU}
    caps = (3.0, 3.5, SERVO_CAP_FPU, 4.3, 4.9, 55.0 * 2.0 * np.pi / 60.0)
    shears = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0)
    scan = []
    for material, bags in runs.items():
        chosen = static[material]["fits"][CHOSEN[material]]
        fitted = world_of(chosen["values"])
        for bag in bags:
            worlds = {"default": world_of({}, DisturbanceModel()), "static_fit": fitted}
            if material == "fpu":
                loro = world_of(chosen["leave_one_run_out"][bag]["values"])
                unscaled = world_of(static[material]["fits"]["actuation + shear offset"]["values"])
                worlds |= {
                    "static_fit_shear_1_speed_cap": world_of(cap, unscaled),
                    "speed_cap": world_of(cap, DisturbanceModel()),
                    "static_fit_speed_cap": world_of(cap, fitted),
                    "loro_static_fit": loro,
                    "loro_static_fit_speed_cap": world_of(cap, loro),
                }
            t0 = time.perf_counter()
            run = calibrate.prepare_run(bag)
            sims = calibrate.simulate(run, list(worlds.values()))
            robot_offsets = end_offsets(run.robot, run.steps)
            rows = {}
            for label, sim in zip(worlds, sims):
                c = sim_to_real.compare(sim, run.robot, run.steps)
                offsets = end_offsets(sim, run.steps)
                rows[label] = {
                    "D_mm": c.deviation * 1e3,
                    "x_p2p_max_mm": [v * 1e3 for v in c.x_peak_to_peak],
                    "end_error_median_mm": [v * 1e3 for v in c.end_error],
                    "rise_time_median_rel_diff": c.rise_time_difference,
                    "rmse_mm": [v * 1e3 for v in c.rmse],
                    "onset_median_s": [
                        float(np.nanmedian(sim_to_real.onset_times(s, run.steps)))
                        for s in (sim, run.robot)
                    ],
                    "end_offset_x_mm": offsets[:, 0].round(3).tolist(),
                    "end_offset_rms_vs_robot_mm": float(
                        np.sqrt(np.mean(np.sum((offsets - robot_offsets) ** 2, axis=1)))
                    ),
                }
            if material == "fpu":
                capped = [world_of({"servo_max_speed": v}, fitted) for v in caps]
                capped += [world_of({"shear_scale": v}, world_of(cap, fitted)) for v in shears]
                scan.append(calibrate.deviations(run, capped))
            out["runs"][bag] = {
                "note": run.note,
                "worlds": {k: dataclasses.asdict(w) for k, w in worlds.items()},
                "robot_end_offset_x_mm": robot_offsets[:, 0].round(3).tolist(),
                "results": rows,
                "wall_s": time.perf_counter() - t0,
            }
            print(bag, json.dumps(rows, default=float)[:1500], flush=True)
    pooled = (calibrate.pooled(scan) * 1e3).tolist()
    out["fpu_speed_cap_scan_static_fit"] = {
        "servo_max_speed": list(caps),
        "pooled_D_mm": pooled[: len(caps)],
    }
    out["fpu_shear_scale_scan_static_fit_speed_cap"] = {
        "shear_scale": list(shears),
        "pooled_D_mm": pooled[len(caps) :],
    }
    return out


def main() -> None:
    """Run the analysis and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--closed-loop", action="store_true", help="also the batched closed loop")
    args = parser.parse_args()
    configure_jax()
    t0 = time.perf_counter()
    runs = {m: static_mismatch.material_runs(m) for m in CHOSEN}
    result = {
        "what": "static plant/model mismatch fitted to the real runs' end-of-step pairs (φ, p)",
        "window_s": WINDOW,
        "declared_world": DECLARED,
        "chosen_field_sets": CHOSEN,
    }
    for material, bags in runs.items():

        def progress(label: str, res: dict, material: str = material) -> None:
            print(material, label, json.dumps(res, default=float)[:300], flush=True)

        result[material] = static_mismatch.static_analysis(material, bags, progress)
    result["static_wall_s"] = time.perf_counter() - t0
    if args.closed_loop:
        result["closed_loop"] = closed_loop(result, runs)
    result["machine"] = platform.platform()
    result["wall_s"] = time.perf_counter() - t0
    OUT.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

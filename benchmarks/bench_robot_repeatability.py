"""How well the September FPU robot repeats itself, and what that leaves for a simulator to match.

The two FPU P-satI-D runs of 2023-09-25 (20230925_093236, P-satI-D; 20230925_094023, P-satI-D +
gravity compensation) have the same setpoints at the same step sizes and the same gains; the laws
differ by the gravity term only, which acts at rest. This compares them with the measure of issue 20
(hsa_core.analysis.sim_to_real: each step aligned at its own instant, steps 1–10, first 9.3 s,
100 Hz):

* D between the two robot runs, per step and per window after the step;
* the onset of every step (first instant the end effector is 1 mm from where it was at the step);
* the offline experiment in the calibrated world, each run with its own conditions (what
  ``bench_sim_to_real.py``'s ``own_profile_calibrated_world`` rows run), against each robot run and
  against the mean of the two robot responses;
* the simulator against itself: each run replayed with ``--noise-seeds`` mocap noise realizations
  (default 16), D between every two of them and their onsets (under the September command queue a
  realization decides the driver's backlog at each step, as the robot's own runs differ), and the
  onsets' spread over every step of every realization beside the robot's over its 20 steps.

Two independent realisations of a process that differ by D_rr are each D_rr / √2 (RMS) from its
mean, and the mean of the two is D_rr / 2 from it: a deterministic simulator of the mean robot
cannot be expected below those against one run and against the two-run mean. Writes
benchmarks/results/robot_repeatability.json.

    .venv/bin/python benchmarks/bench_robot_repeatability.py [--noise-seeds N] [--out FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]
RUNS = ("20230925_093236", "20230925_094023")
WINDOWS = ((0.0, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 2.0), (2.0, 5.0), (5.0, 9.3))
ONSET = 1e-3  # [m] distance from the pose at the step that marks the onset


def _summary(diff: np.ndarray, grid: float) -> dict:
    """D [mm], D per step and per window after the step, and each window's share of D², of the
    aligned differences ``diff`` (steps, samples, 2) [m]."""
    sq = np.sum(diff**2, axis=-1)
    t = np.arange(diff.shape[1]) * grid
    windows = {}
    for lo, hi in WINDOWS:
        m = (t >= lo) & (t < hi)
        windows[f"{lo}-{hi} s"] = {
            "rms_mm": round(float(np.sqrt(np.mean(sq[:, m]))) * 1e3, 3),
            "share_of_D2": round(float(np.sum(sq[:, m]) / np.sum(sq)), 3),
        }
    return {
        "D_mm": round(float(np.sqrt(np.mean(sq))) * 1e3, 3),
        "D_per_step_mm": [round(float(v) * 1e3, 2) for v in np.sqrt(np.mean(sq, axis=1))],
        "windows": windows,
    }


def _onsets(aligned: np.ndarray, grid: float) -> list[float]:
    """[s] per step: the first sample 1 mm from the pose at the step."""
    dist = np.linalg.norm(aligned - aligned[:, :1], axis=-1)
    return [round(float(np.argmax(row > ONSET)) * grid, 3) for row in dist]


def _spread(onsets: list[float]) -> dict:
    """Median, 90th percentile and maximum [s] of ``onsets``, and how many there are."""
    o = np.asarray(onsets)
    return {
        "steps": int(o.size),
        "median_s": round(float(np.median(o)), 3),
        "p90_s": round(float(np.percentile(o, 90)), 3),
        "max_s": round(float(o.max()), 3),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise-seeds", type=int, default=16)
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "robot_repeatability.json"
    )
    args = parser.parse_args()
    if args.noise_seeds < 2:
        parser.error("argument --noise-seeds: must be >= 2")
    configure_jax()
    from hsa_core.analysis import sim_to_real
    from hsa_core.runs import reference
    from hsa_core.sim.disturbance import calibrated_world
    from hsa_core.sim.experiment import replay_config, run_experiment

    grid = sim_to_real.GRID
    robots, sims = {}, {}
    started = time.perf_counter()
    realizations = {}
    for bag in RUNS:
        real = reference.load_run(bag)
        robots[bag] = sim_to_real.aligned_responses(
            sim_to_real.StepRun(real.t, real.p, real.p_des, 110.0)
        )
        realizations[bag] = []
        for seed in range(args.noise_seeds):
            world = calibrated_world("fpu", seed=seed)
            log = run_experiment(dataclasses.replace(replay_config(real), disturbance=world)).log
            realizations[bag].append(
                sim_to_real.aligned_responses(sim_to_real.StepRun.of_log(log, 110.0))
            )
        sims[bag] = realizations[bag][0]
    a, b = RUNS
    mean_robot = (robots[a] + robots[b]) / 2.0
    result = {
        "what": __doc__.splitlines()[0],
        "runs": list(RUNS),
        "robot_vs_robot": _summary(robots[a] - robots[b], grid),
        "onset_s": {
            **{f"robot {bag}": _onsets(robots[bag], grid) for bag in RUNS},
            **{f"sim {bag}": _onsets(sims[bag], grid) for bag in RUNS},
        },
        "sim_calibrated_world": {
            **{f"vs robot {bag}": _summary(sims[bag] - robots[bag], grid) for bag in RUNS},
            **{
                f"sim {bag} vs the mean of the two robot runs": _summary(
                    sims[bag] - mean_robot, grid
                )
                for bag in RUNS
            },
            "each robot run vs the mean of the two": _summary(robots[a] - mean_robot, grid),
        },
        "sim_vs_sim": {
            bag: {
                "noise_seeds": args.noise_seeds,
                "D_mm_between_realizations": [
                    _summary(runs[i] - runs[j], grid)["D_mm"]
                    for i in range(len(runs))
                    for j in range(i + 1, len(runs))
                ],
                "onset_s_per_realization": [_onsets(r, grid) for r in runs],
            }
            for bag, runs in realizations.items()
        },
        "onset_spread": {
            "robot, both runs": _spread([o for bag in RUNS for o in _onsets(robots[bag], grid)]),
            "sim, both runs, every realization": _spread(
                [o for runs in realizations.values() for r in runs for o in _onsets(r, grid)]
            ),
        },
        "machine": {"cpus": 2, "python": platform.python_version()},
        "wall_s": round(time.perf_counter() - started, 1),
    }
    rr = result["robot_vs_robot"]["D_mm"]
    print(f"robot {a} vs robot {b}: D {rr:.2f} mm (D/sqrt(2) = {rr / np.sqrt(2):.2f} mm)")
    for key, row in result["sim_calibrated_world"].items():
        print(f"{key}: D {row['D_mm']:.2f} mm")
    for key, onsets in result["onset_s"].items():
        print(f"onset {key}: {onsets}")
    for bag, row in result["sim_vs_sim"].items():
        d = row["D_mm_between_realizations"]
        print(
            f"sim {bag} vs itself ({args.noise_seeds} noise seeds): D {min(d):.2f}-{max(d):.2f} mm"
        )
    for key, row in result["onset_spread"].items():
        print(f"onsets {key}: {row}")
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

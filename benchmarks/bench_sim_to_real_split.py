"""Where the simulator's distance from the real robot lies: systematic or random, when, which step.

Each reference run (hsa_core/config/realdata) is replayed with its own conditions in the calibrated
world (``hsa_experiment --run BAG``) over ``--noise-seeds`` mocap noise realizations, and its D
(issue 20's measure, hsa_core.analysis.sim_to_real) is split exactly
(:func:`hsa_core.analysis.sim_to_real.split_realizations`): RMS over realizations of D² = D of the
realizations' mean response² (systematic) + their RMS distance from that mean² (spread). The split
is given over the whole 9.3 s after each step and over windows of it, the systematic part per step,
and each step's onset (10 % of the way) in the robot and in the realizations. A run without the
September command queue (the October EPU run) differs between realizations by about 0.01 mm: it is
given two. The systematic part includes spread²/N of N realizations.

The robot repeats itself only so well: its two September P-satI-D runs (093236, 094023) are
``robot_pair_D`` apart. A simulator that were the robot's exact stochastic twin would be that far
from one robot run on average (both draws from one distribution); the robot's own randomness is
inside each run's systematic part, so ``bias_estimate`` = √(systematic² − robot_pair_D²/2) is the
part no realization of the robot would show (an estimate: two robot runs, one of each law).

    .venv/bin/python benchmarks/bench_sim_to_real_split.py [--noise-seeds N] [--out FILE]

Writes benchmarks/results/sim_to_real_split.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import results_doc

ROOT = Path(__file__).resolve().parents[1]
WINDOWS = ((0.0, 0.15), (0.15, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 2.0), (2.0, 9.3))
"""[s] after each step: the parts of the aligned responses reported separately."""
PAIR = ("20230925_093236", "20230925_094023")
"""The robot's two September P-satI-D runs (without and with gravity compensation)."""


def _mm(v: float) -> float:
    return round(float(v) * 1e3, 3)


def _windows(sims: list, robot, rms: float) -> dict:  # noqa: ANN001 - StepRun
    """The split over each of WINDOWS, with the window's share of the run's mean D²."""
    from hsa_core.analysis import sim_to_real

    out = {}
    for a, b in WINDOWS:
        part = sim_to_real.split_realizations(sims, robot, window=(a, b))
        out[f"{a}-{b}"] = {
            "rms": _mm(part.rms),
            "systematic": _mm(part.systematic),
            "spread": _mm(part.spread),
            "share_of_D2": round(part.rms**2 * (b - a) / sim_to_real.HORIZON / rms**2, 3),
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise-seeds", type=int, default=16)
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "sim_to_real_split.json"
    )
    args = parser.parse_args()
    if args.noise_seeds < 2:
        parser.error("argument --noise-seeds: must be >= 2 (a spread needs two realizations)")
    from hsa_core.jaxsetup import configure_jax

    configure_jax()
    from hsa_core.analysis import sim_to_real
    from hsa_core.runs import reference
    from hsa_core.sim.experiment import replay_config, run_experiment

    started = time.perf_counter()
    robots = {}
    runs = {}
    for bag in reference.run_names():
        real = reference.load_run(bag)
        robot = robots[bag] = sim_to_real.StepRun(real.t, real.p, real.p_des, 110.0)
        config = replay_config(real)
        sims = [
            sim_to_real.StepRun.of_log(run_experiment(config.in_world(seed=s)).log, 110.0)
            for s in range(args.noise_seeds if config.command_queue[0] else 2)
        ]
        whole = sim_to_real.split_realizations(sims, robot)
        onsets = np.array([sim_to_real.onset_times(s) for s in sims])
        runs[bag] = {
            "law": real.conditions.law.value,
            "material": real.conditions.material,
            "profile": real.conditions.profile.name,
            "noise_seeds": len(sims),
            "D_mm": {
                "rms_over_realizations": _mm(whole.rms),
                "systematic": _mm(whole.systematic),
                "spread": _mm(whole.spread),
            },
            "windows_s": _windows(sims, robot, whole.rms),
            "steps": [
                {
                    "step": k,
                    "systematic_mm": _mm(whole.systematic_per_step[i]),
                    "onset_s": {
                        "robot": round(float(sim_to_real.onset_times(robot)[i]), 3),
                        "sim_median": round(float(np.median(onsets[:, i])), 3),
                        "sim_min": round(float(onsets[:, i].min()), 3),
                        "sim_max": round(float(onsets[:, i].max()), 3),
                    },
                }
                for i, k in enumerate(sim_to_real.STEPS)
            ],
        }
        print(f"{bag}: {json.dumps(runs[bag]['D_mm'])}", flush=True)
    pair = sim_to_real.deviation(robots[PAIR[0]], robots[PAIR[1]])
    for bag in PAIR:
        systematic = runs[bag]["D_mm"]["systematic"] * 1e-3
        runs[bag]["bias_estimate_mm"] = _mm(np.sqrt(max(systematic**2 - pair**2 / 2, 0.0)))
    doc = {
        "what": __doc__.splitlines()[0],
        "command": f"benchmarks/bench_sim_to_real_split.py --noise-seeds {args.noise_seeds}",
        "world": "calibrated (hsa_core.sim.disturbance.calibrated_world); each run's own "
        "conditions (hsa_core.sim.experiment.replay_config)",
        "split": "rms_over_realizations^2 = systematic^2 + spread^2 (per window too); share_of_D2: "
        "the window's part of the run's mean squared distance",
        "robot_pair_D_mm": {f"{PAIR[0]} vs {PAIR[1]}": _mm(pair)},
        "runs": runs,
        "wall_s": round(time.perf_counter() - started, 1),
    }
    results_doc.write(args.out, doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What the reference runs say about the mocap noise σ, and the simulator's end-of-step peak-to-peak
at that σ against the robot's.

Per material and axis (hsa_core.sysid.mocap_noise): the upper bound on white noise σ from the
vertex counts of every rest window (last 2 s of each step) of the material's runs (censored: creep
and level switching only add vertices), leave-one-run-out for FPU (three runs), and the
maximum-likelihood σ if every vertex of the flat windows were noise (an over-estimate). Then each
run is replayed (hsa_core.sim.experiment.replay_config, the material's calibrated world, seed 0;
as replay_config gives it) with the pose noise declared today and with the bound on x and y
(θ as declared, or scaled by the bound's ratio to the declared x noise), and its x peak-to-peak
(max over steps 1–10, last 2 s) is compared with the robot's: raw (the sim's ticks) and at the
data's resolution (the sim's trace simplified as the run's figure was, on the 10 ms grid of the
robot's trace).

θ (``--q-eps DIR``, the authors' ``<bag>_q.eps`` files, tud-phi/hsa-planar-control f1ed958
``data/experiments/<bag>/``, not packaged here): the same bound on the noise of the plotted κ_be,
which the controller's inverse kinematics makes θ_b / l (hsa_core.model.kinematics), so σ_θ = l·σ_κ.
The κ_be line is the file's first long polyline; its windows are counted in the file (steps 0–9:
the last step's window holds the vertices the simplifier adds at the end of the path). Writes
benchmarks/results/mocap_noise.json. The pooled bound of all four runs (one OptiTrack system for
both materials) is the mocap noise of the rest world (hsa_core.sim.disturbance.rest_world); with
``--write-world`` it goes to hsa_core/hsa_core/config/world/mocap_noise.yaml.

    .venv/bin/python benchmarks/bench_mocap_noise.py [--replicates 1000] [--no-sim] [--q-eps DIR]
        [--write-world]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import numpy as np
import yaml

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]
MATERIALS = {
    "fpu": ["20230925_092200", "20230925_093236", "20230925_094023"],
    "epu": ["20231019_143126"],
}
SIGMAS = np.concatenate([[0.0], np.geomspace(1e-7, 1e-4, 61)])
"""[m] the σ grid (12 % steps)."""
DECLARED = (1e-4, 1e-4, 1e-3)
"""DisturbanceModel().pose_noise_std today [m, m, rad]."""
ROBOT_P2P_TARGET = 0.5e-3


def estimates(bags: list[str], replicates: int) -> dict:
    """Per axis: the upper bound, the all-noise estimate and interval [m]."""
    from hsa_core.sysid import mocap_noise as mn

    out = {}
    for axis, name in enumerate("xy"):
        windows = mn.observed(bags, axis)
        flat = mn.observed(bags, axis, flat_only=True)
        bound, _ = mn.upper_bound(windows, SIGMAS, replicates)
        est, _ = mn.all_noise_estimate(flat, SIGMAS, replicates)
        out[name] = {
            "upper_bound_95": bound,
            "all_noise_mle": est.value,
            "all_noise_interval_95": [est.low, est.high],
            "windows": len(windows),
            "windows_zero_vertices": sum(n == 0 for n, _ in windows),
            "windows_flat": len(flat),
        }
    return out


EPS_UNIT = 0.012
"""[pt] the user unit of the authors' EPS files (their ``0.012 0 0 0.012 0 0 cm``)."""


def _polylines(path: Path) -> list[np.ndarray]:
    """The EPS file's polylines of more than 50 points (n, 2) [EPS units], in file order."""
    lines: list[list[tuple[float, float]]] = []
    for row in path.read_text(errors="replace").splitlines():
        parts = row.split()
        if len(parts) != 3 or parts[2] not in ("m", "l"):
            continue
        try:
            point = (float(parts[0]), float(parts[1]))
        except ValueError:
            continue
        if parts[2] == "m":
            lines.append([point])
        elif lines:
            lines[-1].append(point)
    return [np.array(line) for line in lines if len(line) > 50]


def theta_bound(q_dir: Path, bags: list[str], replicates: int) -> dict:
    """The bound on σ_θ [rad] from the κ_be lines of ``bags``' ``_q.eps`` figures."""
    import csv

    from hsa_core.model.params import load_params
    from hsa_core.runs.reference import DATA_DIR
    from hsa_core.sysid import mocap_noise as mn

    windows, counts, tolerance = [], {}, {}
    for bag in bags:
        kappa = _polylines(q_dir / f"{bag}_q.eps")[0]
        with (DATA_DIR / f"{bag}_q.csv").open() as f:
            table = np.array([[float(v) for v in row] for row in list(csv.reader(f))[1:]])
        t = table[:, 0]
        span = kappa[-1, 0] - kappa[0, 0]
        t_vertex = t[0] + (kappa[:, 0] - kappa[0, 0]) / span * (t[-1] - t[0])
        scale = np.polyfit(np.interp(t_vertex, t, table[:, 2]), kappa[:, 1], 1)[0]
        with (DATA_DIR / f"{bag}_step_metrics.csv").open() as f:
            steps = list(csv.DictReader(f))[:-1]
        geometry = mn.Geometry(
            float(steps[0]["dt_sample_est"]),
            span * EPS_UNIT / (t[-1] - t[0]),
            scale * EPS_UNIT,
        )
        tolerance[bag] = geometry.tolerance
        ends = [float(row["t_end"]) for row in steps]
        counts[bag] = [int(np.sum((t_vertex >= e - mn.WINDOW) & (t_vertex < e))) for e in ends]
        windows += [(n, geometry) for n in counts[bag]]
    length = float(load_params(_material(bags)).l)
    bound, _ = mn.upper_bound(windows, SIGMAS * 1e3, replicates)
    est, _ = mn.all_noise_estimate(windows, SIGMAS * 1e3, replicates)
    return {
        "rod_length_m": length,
        "kappa_tolerance_rad_per_m": tolerance,
        "window_vertices": counts,
        "upper_bound_95": bound * length,
        "all_noise_mle": est.value * length,
        "all_noise_interval_95": [est.low * length, est.high * length],
    }


def _material(bags: list[str]) -> str:
    """The material of ``bags`` (MATERIALS)."""
    return next(m for m, runs in MATERIALS.items() if set(bags) <= set(runs))


def sim_p2p(bag: str, std: tuple[float, float, float]) -> dict:
    """x peak-to-peak [m] (max over steps) of the replay at pose noise ``std``, raw and as drawn,
    and the robot's."""
    from hsa_core.analysis import sim_to_real
    from hsa_core.runs import reference
    from hsa_core.sim.disturbance import calibrated_world
    from hsa_core.sim.experiment import replay_config, run_experiment
    from hsa_core.sysid import mocap_noise as mn

    real = reference.load_run(bag)
    config = replay_config(real)
    world = dataclasses.replace(calibrated_world(real.conditions.material), pose_noise_std=std)
    wall0 = time.perf_counter()
    log = run_experiment(dataclasses.replace(config, disturbance=world)).log
    wall = time.perf_counter() - wall0
    t, p, p_des = log.t, log.chiee[:, :2], log.chiee_des[:, :2]
    sim = sim_to_real.StepRun(t, p, p_des, 110.0)
    robot = sim_to_real.StepRun(real.t, real.p, real.p_des, 110.0)
    geometry = mn.run_geometry(bag)
    drawn = np.stack([mn.as_drawn(t, p[:, i], geometry) for i in range(2)], axis=1)
    grid = np.arange(t[0], t[-1], 0.01)
    setpoint = p_des[np.searchsorted(t, grid, side="right") - 1]
    at_res = np.stack([np.interp(grid, t, drawn[:, i]) for i in range(2)], axis=1)
    sim_drawn = sim_to_real.StepRun(grid, at_res, setpoint, 110.0)
    raw = sim_to_real.end_peak_to_peak(sim)[:, 0]
    res = sim_to_real.end_peak_to_peak(sim_drawn)[:, 0]
    return {
        "pose_noise_std": list(std),
        "x_p2p_sim_raw": float(raw.max()),
        "x_p2p_sim_at_data_resolution": float(res.max()),
        "x_p2p_robot": sim_to_real.compare(sim, robot).x_peak_to_peak[1],
        "x_p2p_sim_raw_per_step": raw.tolist(),
        "x_p2p_sim_at_data_resolution_per_step": res.tolist(),
        "x_p2p_robot_per_step": sim_to_real.end_peak_to_peak(robot)[:, 0].tolist(),
        "wall_s": wall,
    }


def main() -> int:
    """Estimate per material, leave-one-run-out, replay; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicates", type=int, default=1000)
    parser.add_argument("--no-sim", action="store_true", help="only the σ estimates")
    parser.add_argument("--q-eps", type=Path, help="folder of the authors' <bag>_q.eps files")
    parser.add_argument(
        "--write-world",
        action="store_true",
        help="also write the pooled bound on x and y to config/world/mocap_noise.yaml",
    )
    args = parser.parse_args()
    configure_jax()
    out: dict = {
        "machine": platform.node(),
        "replicates": args.replicates,
        "sigma_grid_m": [float(SIGMAS[1]), float(SIGMAS[-1]), len(SIGMAS)],
        "target_x_p2p": ROBOT_P2P_TARGET,
        "materials": {},
    }
    for material, bags in MATERIALS.items():
        t0 = time.perf_counter()
        entry = {"runs": bags, "estimate": estimates(bags, args.replicates)}
        if len(bags) > 1:
            entry["leave_one_run_out"] = {
                left: estimates([b for b in bags if b != left], args.replicates) for left in bags
            }
        if args.q_eps:
            entry["estimate"]["theta"] = theta_bound(args.q_eps, bags, args.replicates)
            if len(bags) > 1:
                for left in bags:
                    entry["leave_one_run_out"][left]["theta"] = theta_bound(
                        args.q_eps, [b for b in bags if b != left], args.replicates
                    )
        entry["estimate_wall_s"] = time.perf_counter() - t0
        bound = entry["estimate"]
        std = (bound["x"]["upper_bound_95"], bound["y"]["upper_bound_95"])
        scaled_theta = DECLARED[2] * max(std) / DECLARED[0]
        if not args.no_sim:
            entry["sim"] = {
                bag: {
                    "declared": sim_p2p(bag, DECLARED),
                    "bound_theta_declared": sim_p2p(bag, (*std, DECLARED[2])),
                    "bound_theta_scaled": sim_p2p(bag, (*std, scaled_theta)),
                }
                for bag in bags
            }
        out["materials"][material] = entry
        print(json.dumps({material: entry["estimate"]}, indent=1), flush=True)
    everything = [bag for bags in MATERIALS.values() for bag in bags]
    pooled = {"runs": everything, "estimate": estimates(everything, args.replicates)}
    pooled["leave_one_run_out"] = {
        left: estimates([b for b in everything if b != left], args.replicates)
        for left in everything
    }
    out["pooled"] = pooled
    print(json.dumps({"pooled": pooled["estimate"]}, indent=1), flush=True)
    if args.write_world:
        from hsa_core.sim.disturbance import WORLD_DIR
        from hsa_core.sysid import mocap_noise as mn

        doc = mn.world_document(
            pooled["estimate"]["x"]["upper_bound_95"],
            pooled["estimate"]["y"]["upper_bound_95"],
            everything,
            "benchmarks/bench_mocap_noise.py --write-world",
        )
        (WORLD_DIR / "mocap_noise.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    path = ROOT / "benchmarks" / "results" / "mocap_noise.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

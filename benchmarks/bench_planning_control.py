"""Benchmark of hsa_core.task.planning and hsa_core.controller.control against the original figures
(reference_performance.md).

Each section runs in a fresh process with hsa_core's persistent compilation cache disabled, so
"cold" includes tracing and XLA compilation as a first start pays it; one extra run measures a
restart that finds the cache filled. Writes benchmarks/results/planning_control.json. Usage: python
benchmarks/bench_planning_control.py [--quick] (--quick skips the spec-faithful rollout LM from phi0
= 0, which takes minutes).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hsa_core.task.trajectories import STEP_LISTS

RESULTS = Path(__file__).resolve().parent / "results" / "planning_control.json"
EPU_STEPS = STEP_LISTS["epu"]  # experiments.md §2

# reference_performance.md, FPU/EPU run 1 and run 2 (p50 / p95 / max unless stated)
ORIGINAL = {
    "static_lm_startup_s": [10.6, 11.3],
    "static_lm_per_setpoint_s": [[1.39, 1.74, 1.94], [1.42, 1.96, 2.02]],
    "static_lm_compiled_once_ms": [[2.57, 4.51, 4.86], [2.21, 3.46, 3.95]],
    "pg_image_mode_warm_ms": [[1.8, 3.83, 6.04], [1.89, 2.34, 6.48]],
    "rollout_lm_cold_s": [104.0, 101.0],
    "rollout_lm_warm_per_setpoint_s": [[20.7, 22.3, 22.7], [34.5, 42.6, 44.8]],
    "one_rollout_s": [1.07, 1.06],
    "one_rollout_jacfwd_s": [2.34, 2.01],
    "psatid_startup_s": {"fpu": [0.333, 0.535], "epu": [0.442, 0.454]},
    "psatid_control_fn_us": {
        "fpu": [[18.2, 25.4, 57.2], [18.7, 36.4, 70.7]],
        "epu": [[18.7, 39.3, 60.2], [18.2, 32.6, 56.5]],
    },
    "psatid_node_callback_us": {
        "fpu": [[1054, 1331, 2108], [1144, 2145, 2503]],
        "epu": [[1159, 2007, 2376], [1067, 1840, 2433]],
    },
    "psatid_gc_startup_s": {"fpu": [1.93, 2.23], "epu": [1.93, 1.86]},
    "psatid_gc_control_fn_us": {
        "fpu": [[62.4, 103, 139], [62.3, 122, 169]],
        "epu": [[133, 171, 199], [72.2, 145, 181]],
    },
    "psatid_gc_node_callback_us": {
        "fpu": [[1143, 1963, 5311], [1316, 2586, 3086]],
        "epu": [[1191, 1801, 2237], [1771, 2728, 4056]],
    },
    "pid_startup_s": {"fpu": [0.117, 0.101], "epu": [0.132, 0.14]},
    "pid_control_fn_us": {
        "fpu": [[16.3, 21.8, 44.5], [15.9, 24.1, 44.0]],
        "epu": [[16.0, 24.7, 51.5], [17.7, 38.5, 68.0]],
    },
    "pid_node_callback_us": {
        "fpu": [[967, 2402, 2518], [1149, 2236, 2373]],
        "epu": [[1042, 1496, 2098], [1116, 2282, 2486]],
    },
}
TARGETS = {
    "static_inversion_p95_ms": 10.0,
    "epu_planning_warm_s": 0.5,
    "controller_tick_p99_ms": 0.5,
}


def stats(samples: list[float], scale: float = 1.0) -> dict[str, float]:
    """p50 / p95 / p99 / max of a sample list, scaled (e.g. 1e3 for ms)."""
    a = np.asarray(samples) * scale
    percentiles = {
        k: float(np.percentile(a, q)) for k, q in (("p50", 50), ("p95", 95), ("p99", 99))
    }
    return percentiles | {"max": float(a.max()), "n": len(a)}


def timed_plans(planner, points, warm_start: bool, passes: int) -> tuple[list[float], list]:
    """Plan every point, ``passes`` times over: wall time per plan [s] and the results (each must
    succeed)."""
    walls, results = [], []
    for _ in range(passes):
        for p in points:
            t = time.perf_counter()
            r = planner.plan(p, warm_start=warm_start)
            walls.append(time.perf_counter() - t)
            assert r.success, r.message
            results.append(r)
    return walls, results


def section_static(material: str) -> dict:
    """Static inversion: cold (construction incl. compile + first plan), warm fresh and warm-started
    over 5 passes."""
    from hsa_core.model.params import load_params
    from hsa_core.task.planning import Planner

    steps = STEP_LISTS[material]
    t0 = time.perf_counter()
    planner = Planner(load_params(material), "static")
    t_construct = time.perf_counter() - t0
    first = planner.plan(steps[0], warm_start=False)
    cold = time.perf_counter() - t0
    out: dict = {
        "cold_s": cold,
        "construct_s": t_construct,
        "cold_first_plan_status": first.status.name,
    }
    for mode, warm in (("fresh_start", False), ("warm_start", True)):
        planner.reset_warm_start()
        walls, results = timed_plans(planner, steps, warm, passes=5)
        iters = [r.iterations for r in results]
        out[mode] = {
            "per_setpoint_ms": stats(walls, 1e3),
            "iterations_min_max": [min(iters), max(iters)],
            "max_optimality_error": max(r.optimality_error for r in results),
        }
    return out


def section_rollout(full: bool) -> dict:
    """EPU rollout planner: cold construction, warm per setpoint (seeded), one rollout, one jacfwd,
    unseeded LM."""
    import jax

    from hsa_core.model.params import load_params
    from hsa_core.task import planning
    from hsa_core.task.planning import Planner

    params = load_params("epu")
    t0 = time.perf_counter()
    planner = Planner(params, "rollout")
    construct = time.perf_counter() - t0
    planner.plan(EPU_STEPS[0], warm_start=False)
    out: dict = {"cold_s": time.perf_counter() - t0, "construct_s": construct}
    walls, cpus, iters = [], [], []
    for p in EPU_STEPS:
        t, c = time.perf_counter(), time.process_time()
        r = planner.plan(p, warm_start=False)
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
        assert r.success, r.message
        iters.append(r.iterations)
    out["warm_per_setpoint_s"] = stats(walls)
    out["warm_per_setpoint_process_cpu_s"] = stats(cpus)
    out["iterations_min_max"] = [min(iters), max(iters)]
    phi = np.array([3.97701721, 2.51175997])
    t = time.perf_counter()
    jax.block_until_ready(planning.rollout_steady_state(params, phi))
    out["one_rollout_s"] = time.perf_counter() - t
    t = time.perf_counter()
    jax.block_until_ready(planning._rollout_jacobian(params, phi))
    out["one_rollout_jacfwd_first_call_s"] = time.perf_counter() - t
    t = time.perf_counter()
    jax.block_until_ready(planning._rollout_jacobian(params, phi))
    out["one_rollout_jacfwd_s"] = time.perf_counter() - t
    if full:
        lo, hi = np.zeros(2), np.asarray(params.phi_max)
        t = time.perf_counter()
        sol = planning._solve_rollout(params, np.asarray(EPU_STEPS[0]), np.zeros(2), lo, hi, 100)
        out["unseeded_lm_from_phi0_zero"] = {
            "setpoint_1_s": time.perf_counter() - t,
            "evaluations": int(sol.iterations),
            "residual_m": float(sol.residual_norm),
            "phi_ss": np.asarray(sol.x).tolist(),
        }
    return out


def section_default_epu() -> dict:
    """The default EPU planner (bounded static inversion), warm per setpoint."""
    from hsa_core.model.params import load_params
    from hsa_core.task.planning import Planner

    planner = Planner(load_params("epu"))
    walls, _ = timed_plans(planner, EPU_STEPS, warm_start=False, passes=5)
    return {"planner": planner.kind, "warm_per_setpoint_s": stats(walls)}


def section_control(material: str) -> dict:
    """One tick of each law incl. NumPy conversion in and out, with varying measurements (5000 ticks
    each)."""
    from hsa_core.controller.control import Controller, EeIntegralGains
    from hsa_core.model.params import load_params
    from hsa_core.task.planning import Planner

    params = load_params(material)
    setpoint = Planner(params).plan(STEP_LISTS[material][1]).setpoint
    rng = np.random.default_rng(0)
    n = 5000
    q = setpoint.q_des + rng.normal(scale=[0.3, 0.002, 0.005], size=(n, 3))
    q_dot = rng.normal(scale=[1.0, 0.02, 0.05], size=(n, 3))
    chiee = setpoint.chiee_des + rng.normal(scale=[5e-4, 5e-4, 5e-3], size=(n, 3))
    chiee_dot = rng.normal(scale=[5e-3, 5e-3, 5e-2], size=(n, 3))
    out = {}
    for name, kind, ext in (
        ("psatid", "psatid", None),
        ("psatid_gc", "psatid_gc", None),
        ("pid", "pid", None),
        ("psatid_ee_integral", "psatid", EeIntegralGains()),
    ):
        t0 = time.perf_counter()
        c = Controller(kind, params, ee_integral=ext)
        startup = time.perf_counter() - t0
        c.set_setpoint(setpoint)
        ticks, cpus = [], []
        for k in range(n):
            t, cpu = time.perf_counter(), time.process_time()
            c.step(q[k], q_dot[k], chiee[k], chiee_dot[k])
            ticks.append(time.perf_counter() - t)
            cpus.append(time.process_time() - cpu)
        out[name] = {
            "startup_s": startup,
            "tick_incl_numpy_us": stats(ticks, 1e6),
            "tick_process_cpu_us": stats(cpus, 1e6),
        }
    return out


SECTIONS = {
    "static_fpu": lambda full: section_static("fpu"),
    "static_epu": lambda full: section_static("epu"),
    "default_epu": lambda full: section_default_epu(),
    "rollout_epu": section_rollout,
    "control_fpu": lambda full: section_control("fpu"),
    "control_epu": lambda full: section_control("epu"),
}


def run_section(name: str, full: bool, cache_dir: str = "") -> dict:
    """Run one section in a fresh interpreter (persistent compilation cache off unless cache_dir)
    and return its JSON result with the load average around it."""
    load_before = os.getloadavg()[0]
    cmd = [sys.executable, __file__, "--section", name] + ([] if full else ["--quick"])
    env = os.environ | {"HSA_JAX_CACHE_DIR": cache_dir}
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["load_average_1min_before_after"] = [load_before, os.getloadavg()[0]]
    return result


def summary(r: dict) -> dict:
    """Our headline figures next to the original ones and the targets."""
    tick_p99 = {
        f"{m}/{law}": r[f"control_{m}"][law]["tick_incl_numpy_us"]["p99"] / 1e3
        for m in ("fpu", "epu")
        for law in ("psatid", "psatid_gc", "pid", "psatid_ee_integral")
    }
    static_p95 = max(
        r[s][mode]["per_setpoint_ms"]["p95"]
        for s in ("static_fpu", "static_epu")
        for mode in ("fresh_start", "warm_start")
    )
    rollout = r["rollout_epu"]["warm_per_setpoint_s"]
    default_epu = r["default_epu"]["warm_per_setpoint_s"]
    return {
        "static_inversion_p95_ms": {
            "ours_max_over_fpu_epu_fresh_warm": static_p95,
            "target": TARGETS["static_inversion_p95_ms"],
            "met": static_p95 <= TARGETS["static_inversion_p95_ms"],
            "original_per_setpoint_p95_ms": [1740, 1960],
            "original_compiled_once_p95_ms": [4.51, 3.46],
        },
        "static_inversion_cold_s": {
            "ours_fpu": r["static_fpu"]["cold_s"],
            "ours_fpu_restart_with_persistent_cache": r["static_fpu_persistent_cache_restart"][
                "cold_s"
            ],
            "original_startup_s": ORIGINAL["static_lm_startup_s"],
        },
        "epu_default_planner_warm_s": {
            "ours_p95": default_epu["p95"],
            "target": TARGETS["epu_planning_warm_s"],
            "met": default_epu["p95"] <= TARGETS["epu_planning_warm_s"],
            "original_rollout_lm_p50_s": [20.7, 34.5],
        },
        "epu_rollout_planner_warm_s": {
            "ours_p50": rollout["p50"],
            "ours_p95": rollout["p95"],
            "target": TARGETS["epu_planning_warm_s"],
            "met": rollout["p95"] <= TARGETS["epu_planning_warm_s"],
            "original_p50_s": [20.7, 34.5],
        },
        "controller_tick_p99_ms": {
            "ours": tick_p99,
            "target": TARGETS["controller_tick_p99_ms"],
            "met": all(v <= TARGETS["controller_tick_p99_ms"] for v in tick_p99.values()),
            "original_node_callback_p50_ms": {"psatid": 1.054, "psatid_gc": 1.143, "pid": 0.967},
        },
    }


def main() -> None:
    """Run all sections (or one, internally) and write the JSON file."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--section", choices=sorted(SECTIONS))
    parser.add_argument(
        "--quick", action="store_true", help="skip the unseeded rollout LM (minutes)"
    )
    args = parser.parse_args()
    if args.section:
        from hsa_core.jaxsetup import configure_jax

        configure_jax()

        print(json.dumps(SECTIONS[args.section](not args.quick)))
        return
    results = {name: run_section(name, not args.quick) for name in SECTIONS}
    with (
        tempfile.TemporaryDirectory() as cache
    ):  # a restarted node with hsa_core's persistent compilation cache
        run_section("static_fpu", False, cache)
        results["static_fpu_persistent_cache_restart"] = run_section("static_fpu", False, cache)
    import jax

    doc = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "jax": jax.__version__,
            "platform": platform.platform(),
        },
        "units": "suffix of each key (s, ms, us); stats are p50/p95/p99/max over n samples",
        "note": (
            "wall-clock figures unless named process_cpu (CPU time of all threads of the process); "
            "compare them to see waiting for a CPU on a shared machine "
            "(see load_average_1min_before_after)"
        ),
        "summary": summary(results),
        "sections": results,
        "original": ORIGINAL,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(doc["summary"], indent=2))


if __name__ == "__main__":
    main()

"""Throughput of the batched JAX closed loop (hsa_core.closed_loop) on the 110 s FPU step experiment, P-satI-D.

The batch is split over one XLA host device per core (``--host-devices``), as ``batch_rollout`` splits it over GPUs.
For batch sizes B (``--batches``, default 8 32 128): the first call (compiling with an empty compilation cache,
then running), the wall time of one call after compiling (noise seeds differ per run), runs per minute, and the
process's peak resident memory, and how far the seed-0 run's metrics are from the offline experiment's. For
comparison: one run of the Python experiment loop (``run_experiment``). Target (issue "batched closed loop"): ≥ 500
runs per minute on this machine. Writes benchmarks/results/closed_loop.json.

    .venv/bin/python benchmarks/bench_closed_loop.py [--batches 8 32 128 256]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]
TARGET_RUNS_PER_MIN = 500.0


def metric_vector(m) -> np.ndarray:  # noqa: ANN001 - hsa_core.metrics.RunMetrics
    """RMSE, saturated fraction, mean t_r, t_s, overshoot and e_ss of a run."""
    return np.array([m.rmse, m.saturated_fraction, m.response_time_mean, m.settling_time_mean, m.overshoot_mean,
                     m.steady_state_error_mean])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[8, 32, 128])
    parser.add_argument("--host-devices", type=int, default=os.cpu_count() or 1,
                        help="XLA host devices the batch is split over (default: one per core)")
    args = parser.parse_args()
    if args.host_devices > 1:  # before JAX is imported: one XLA CPU device per core, each runs its shard
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                                   f" --xla_force_host_platform_device_count={args.host_devices}").strip()
    cache = tempfile.TemporaryDirectory(prefix="hsa_jax_cache_")  # empty: each first call is a cold start
    os.environ["HSA_JAX_CACHE_DIR"] = cache.name
    configure_jax()
    import jax

    from hsa_core import closed_loop
    from hsa_core.experiment import ExperimentConfig, run_experiment

    config = ExperimentConfig("fpu", "psatid")
    load_before = os.getloadavg()[0]  # the machine may be shared: the load next to the figures
    started = time.perf_counter()
    offline = run_experiment(config)
    python_loop_s = time.perf_counter() - started
    spec, inputs, constants = closed_loop.prepare(config)
    axes = closed_loop.LoopInputs(None, None, 0, None)
    rows = []
    for batch in args.batches:
        noise = np.stack([closed_loop.noise(config.disturbance, spec, seed=s) for s in range(batch)])
        batched = inputs._replace(noise=noise)
        t0 = time.perf_counter()
        jax.block_until_ready(closed_loop.batch_rollout(spec, batched, constants, axes))  # compiles, then runs
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        logs = jax.block_until_ready(closed_loop.batch_rollout(spec, batched, constants, axes))
        wall = time.perf_counter() - t0
        seed0 = closed_loop.evaluate(spec, jax.tree_util.tree_map(lambda a: a[0], logs))
        got, want = metric_vector(seed0), metric_vector(offline.metrics)  # seed 0 is the offline run's noise
        rows.append({"batch": batch, "first_call_s": round(first, 1), "wall_s": round(wall, 2),
                     "runs_per_min": round(batch / wall * 60.0, 1),
                     "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 0),
                     "seed0_rmse_mm": round(seed0.rmse * 1e3, 4),
                     "seed0_metrics_max_rel_diff_vs_offline": float(np.max(np.abs(got - want) / np.abs(want)))})
        print(rows[-1], flush=True)
    best = max(r["runs_per_min"] for r in rows)
    result = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__,
                    "devices": [str(d) for d in jax.devices()]},
        "experiment": "FPU steps, 110 s, P-satI-D, 40 Hz, default disturbance",
        "first_call": "compiles with an empty compilation cache, then runs once",
        "python_loop_note": "one run_experiment, its model compilations (empty cache) included",
        "python_loop": {"wall_s": round(python_loop_s, 1), "runs_per_min": round(60.0 / python_loop_s, 1),
                        "rmse_mm": round(offline.metrics.rmse * 1e3, 4)},
        "batched": rows,
        "target_runs_per_min": TARGET_RUNS_PER_MIN,
        "target_met": best >= TARGET_RUNS_PER_MIN,
        "load_average_1min_before": round(load_before, 1),
        "load_average_1min_after": round(os.getloadavg()[0], 1),
    }
    out = ROOT / "benchmarks" / "results" / "closed_loop.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    cache.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())

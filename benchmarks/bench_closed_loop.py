"""Throughput of the batched JAX closed loop (hsa_core.sim.closed_loop) on the 110 s FPU step
experiment, P-satI-D.

The batch is split over one XLA host device per core (``--host-devices``), as ``batch_rollout``
splits it over GPUs. For batch sizes B (``--batches``, default 8 32 128): the first call (compiling
with an empty compilation cache, then running), the wall time of one call after compiling (noise
seeds differ per run), runs per minute, and the process's peak resident memory, and how far the
seed-0 run's metrics are from the offline experiment's. For comparison: one run of the Python
experiment loop (``run_experiment``). Target (issue "batched closed loop"): ≥ 500 runs per minute on
this machine.

With ``--cli``, the same experiment end to end through ``hsa_robustness --material fpu --laws
psatid`` at ``--cli-batch`` (default 128), as a user runs it (a process per call, its own
``wall_s``): a warm-up call fills a fresh compilation cache, then ``--n`` N1 and N2 (``--cli-n``,
default 128 256) give the marginal runs per minute (N2 − N1) / (wall_s(N2) − wall_s(N1)), next to
the loop's at that batch; ``--n`` N1 + 16 (a short last batch) gives how many times the loop is
lowered for compilation (JAX's compile log; target 1) and its extra cost. Target (issue 25): ≥ 550
runs per minute marginal. ``--skip-kernel`` runs only this part. Writes
benchmarks/results/closed_loop.json (``--out``).

    .venv/bin/python benchmarks/bench_closed_loop.py [--batches 8 32 128 256] [--cli [--cli-n 128
    256]]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]
TARGET_RUNS_PER_MIN = 500.0
TARGET_CLI_RUNS_PER_MIN = 550.0
LOOP_LOWERING = re.compile(r"Compiling jit\(rollout\)")


def metric_vector(m) -> np.ndarray:  # noqa: ANN001 - hsa_core.analysis.metrics.RunMetrics
    """RMSE, saturated fraction, mean t_r, t_s, overshoot and e_ss of a run."""
    return np.array(
        [
            m.rmse,
            m.saturated_fraction,
            m.response_time_mean,
            m.settling_time_mean,
            m.overshoot_mean,
            m.steady_state_error_mean,
        ]
    )


def cli_run(n: int, batch: int, out: Path, env: dict[str, str]) -> dict:
    """One ``hsa_robustness`` process: its own wall_s and how often it lowered the loop for
    compilation."""
    argv = [
        sys.executable,
        "-m",
        "hsa_core.apps.robustness",
        "--material",
        "fpu",
        "--laws",
        "psatid",
        "--n",
        str(n),
        "--batch",
        str(batch),
        "--out",
        str(out),
    ]
    t0 = time.perf_counter()
    done = subprocess.run(
        argv, env=env | {"JAX_LOG_COMPILES": "1"}, capture_output=True, text=True, check=True
    )
    process_s = time.perf_counter() - t0
    wall = json.loads((out / "robustness.json").read_text())["wall_s"]
    return {
        "n": n,
        "batch": batch,
        "wall_s": wall,
        "process_s": round(process_s, 1),
        "loop_compilations": len(LOOP_LOWERING.findall(done.stderr)),
    }


def cli_part(n1: int, n2: int, batch: int, cache: str) -> dict:
    """The CLI's end-to-end figures (module docstring), with a compilation cache the warm-up call
    fills."""
    env = {**os.environ, "HSA_JAX_CACHE_DIR": cache}
    # the CLI makes one XLA device per core itself, as a user's call does
    env.pop("XLA_FLAGS", None)
    with tempfile.TemporaryDirectory(prefix="hsa_cli_") as tmp:
        out = Path(tmp)
        warm = cli_run(batch, batch, out, env)
        rows = [cli_run(n, batch, out, env) for n in (n1, n2, n1 + 16)]
    for row in (warm, *rows):
        print(row, flush=True)
    first, second, tail = rows
    return {
        "command": f"hsa_robustness --material fpu --laws psatid --batch {batch} --n N",
        "warm_up": warm,
        "runs": rows,
        "marginal_runs_per_min": round((n2 - n1) / (second["wall_s"] - first["wall_s"]) * 60.0, 1),
        "tail_extra_s": round(tail["wall_s"] - first["wall_s"], 1),
        "target_marginal_runs_per_min": TARGET_CLI_RUNS_PER_MIN,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[8, 32, 128])
    parser.add_argument(
        "--host-devices",
        type=int,
        default=os.cpu_count() or 1,
        help="XLA host devices the batch is split over (default: one per core)",
    )
    parser.add_argument(
        "--cli", action="store_true", help="also hsa_robustness end to end (module docstring)"
    )
    parser.add_argument("--cli-n", type=int, nargs=2, default=[128, 256], metavar=("N1", "N2"))
    parser.add_argument("--cli-batch", type=int, default=128)
    parser.add_argument(
        "--skip-kernel", action="store_true", help="only the CLI part (implies --cli)"
    )
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "closed_loop.json"
    )
    args = parser.parse_args()
    args.cli |= args.skip_kernel
    if (
        args.host_devices > 1
    ):  # before JAX is imported: one XLA CPU device per core, each runs its shard
        os.environ["XLA_FLAGS"] = (
            os.environ.get("XLA_FLAGS", "")
            + f" --xla_force_host_platform_device_count={args.host_devices}"
        ).strip()
    # empty: each first call is a cold start
    cache = tempfile.TemporaryDirectory(prefix="hsa_jax_cache_")
    os.environ["HSA_JAX_CACHE_DIR"] = cache.name
    configure_jax()
    load_before = os.getloadavg()[0]  # the machine may be shared: the load next to the figures
    if args.skip_kernel and args.out.is_file():
        # the kernel's figures stay, the CLI's are replaced
        result = json.loads(args.out.read_text())
    else:
        result = kernel_part(args.batches)
    if args.cli:
        cli = cli_part(*args.cli_n, args.cli_batch, cache.name)
        kernel = {r["batch"]: r["runs_per_min"] for r in result.get("batched", [])}.get(
            args.cli_batch
        )
        cli["kernel_runs_per_min_same_batch"] = kernel
        cli["marginal_over_kernel"] = (
            round(cli["marginal_runs_per_min"] / kernel, 3) if kernel else None
        )
        cli["target_met"] = cli["marginal_runs_per_min"] >= TARGET_CLI_RUNS_PER_MIN
        cli["load_average_1min_before"] = round(load_before, 1)
        cli["load_average_1min_after"] = round(os.getloadavg()[0], 1)
        result["cli"] = cli
    if not args.skip_kernel:
        result["load_average_1min_before"] = round(load_before, 1)
        result["load_average_1min_after"] = round(os.getloadavg()[0], 1)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    cache.cleanup()
    return 0


def kernel_part(batches: list[int]) -> dict:
    """The loop alone at each batch size, and one run of the Python experiment loop (module
    docstring)."""
    import jax

    from hsa_core.sim import closed_loop
    from hsa_core.sim.disturbance import DisturbanceModel
    from hsa_core.sim.experiment import ExperimentConfig, run_experiment

    config = ExperimentConfig("fpu", "psatid", disturbance=DisturbanceModel())
    started = time.perf_counter()
    offline = run_experiment(config)
    python_loop_s = time.perf_counter() - started
    spec, inputs, constants = closed_loop.prepare(config)
    axes = closed_loop.LoopInputs(None, None, 0, None)
    rows = []
    for batch in batches:
        batched = inputs._replace(
            noise=closed_loop.noise_batch(config.disturbance, spec, np.arange(batch))
        )
        t0 = time.perf_counter()
        # compiles, then runs
        jax.block_until_ready(closed_loop.batch_rollout(spec, batched, constants, axes))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        logs = jax.block_until_ready(closed_loop.batch_rollout(spec, batched, constants, axes))
        wall = time.perf_counter() - t0
        seed0 = closed_loop.evaluate(spec, jax.tree_util.tree_map(lambda a: a[0], logs))
        got, want = (
            metric_vector(seed0),
            metric_vector(offline.metrics),  # seed 0 is the offline run's noise
        )
        rows.append(
            {
                "batch": batch,
                "first_call_s": round(first, 1),
                "wall_s": round(wall, 2),
                "runs_per_min": round(batch / wall * 60.0, 1),
                "peak_rss_mib": round(
                    resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 0
                ),
                "seed0_rmse_mm": round(seed0.rmse * 1e3, 4),
                "seed0_metrics_max_rel_diff_vs_offline": float(
                    np.max(np.abs(got - want) / np.abs(want))
                ),
            }
        )
        print(rows[-1], flush=True)
    best = max(r["runs_per_min"] for r in rows)
    return {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "jax": jax.__version__,
            "devices": [str(d) for d in jax.devices()],
        },
        "experiment": "FPU steps, 110 s, P-satI-D, 40 Hz, declared world",
        "first_call": "compiles with an empty compilation cache, then runs once",
        "python_loop_note": "one run_experiment, its model compilations (empty cache) included",
        "python_loop": {
            "wall_s": round(python_loop_s, 1),
            "runs_per_min": round(60.0 / python_loop_s, 1),
            "rmse_mm": round(offline.metrics.rmse * 1e3, 4),
        },
        "batched": rows,
        "target_runs_per_min": TARGET_RUNS_PER_MIN,
        "target_met": best >= TARGET_RUNS_PER_MIN,
    }


if __name__ == "__main__":
    sys.exit(main())

"""Gain tuning over a Monte-Carlo batch of plants (``hsa_tune``), with the batched JAX loop of
:mod:`closed_loop`.

**Objective** of a gain set g, over the plants P of the batch (weights in ``WEIGHTS``, all per
plant, then the mean):

    J(g) = RMSE [mm] + 0.5 mm/s · t_r [s] + 0.1 · overshoot [mm] + 100 mm/rad · effort [rad] + 5 mm
    · bad

with t_r the mean response time, overshoot the mean overshoot, effort the mean |φ_k − φ_{k−1}| of
the command per tick (chatter the servos would have to follow), and bad = 1 for an unstable or
limit-cycling run (:func:`hsa_core.apps.robustness.classify`). All of them come from
:func:`hsa_core.apps.batch_metrics.evaluate`, one compiled call per batch of runs. RMSE
dominates; the other terms break ties towards fast, calm responses and make an oscillating or
diverging run lose against any settled one.

**Optimiser: derivative-free** (the cross-entropy method on log-gains): sample a population from a
Gaussian in log10(gain), evaluate all of it over all plants in one batched call, refit the Gaussian
to the best fifth, repeat; the paper's gains are a member of the first population. Why not
gradients: the command reaches the servos as whole ticks (``trunc``), whose derivative is zero, so
the exact gradient of any tracking measure with respect to the gains is zero (docs/simulation.md,
"The batched closed loop"). A smooth surrogate (no quantisation, soft clip) used only for gradients
would give a direction, but the speed cap and the limit cycles the objective penalises are where it
and the loop differ most.

**Plants**: :func:`hsa_core.apps.robustness.perturbed_plants` around the plant of the world that
``--disturbance`` names (default the material's calibrated world), in that world and under the run
``--profile`` (default the lab's).

Output in ``--out``: ``gains.yaml`` (a controller_node parameter file with the tuned gains; given
after the material's file it replaces the paper's gains: ``./run.sh --gains FILE``, launch argument
``gains:=FILE``), ``report.json`` (history, before/after on the batch and on the nominal plant) and
``before_after`` box plots (PDF, PNG).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import jax
import matplotlib
import numpy as np
import yaml

from hsa_core import cli
from hsa_core.analysis import plotting
from hsa_core.apps import batch_metrics, robustness
from hsa_core.controller.control import CollocatedGains, ControllerKind, PidGains, default_gains
from hsa_core.jaxsetup import configure_jax, use_every_core
from hsa_core.model.params import load_params
from hsa_core.runs.profiles import DEFAULT_PROFILE, load_profile
from hsa_core.sim import closed_loop
from hsa_core.sim.experiment import profile_config
from hsa_core.task.trajectories import TimedReference, step_reference

WEIGHTS = {"rmse_mm": 1.0, "t_r_s": 0.5, "overshoot_mm": 0.1, "effort_rad": 100.0, "bad": 5.0}
"""Weights of the objective (module docstring), in mm per unit of each term."""
MISSING = {"rmse_mm": 1e3, "t_r_s": 10.0, "overshoot_mm": 0.0, "effort_rad": 0.0, "bad": 1.0}
"""A term a run cannot give (diverged; a step never reached: its whole 10 s count as response
time)."""
TUNED = {
    ControllerKind.PSATID: ("kp", "ki", "kd"),
    ControllerKind.PSATID_GC: ("kp", "ki", "kd"),
    ControllerKind.PID: ("kp", "ki", "kd"),
}
"""Gains the tuner varies (gamma of the collocated laws stays the paper's)."""
LOG_SPAN = 1.0
"""Initial standard deviation of log10(gain): a decade around the paper's value."""
ELITE = 0.2


@dataclass(frozen=True)
class Evaluation:
    """Objective and per-plant terms of one gain set."""

    objective: float
    terms: dict[str, float]
    rmse_mm: np.ndarray


def to_gains(
    kind: ControllerKind, base: CollocatedGains | PidGains, log10: np.ndarray
) -> CollocatedGains | PidGains:
    """The gain set with the tuned gains at 10**log10."""
    return replace(base, **{name: float(f"{10.0**v:.6g}") for name, v in zip(TUNED[kind], log10)})


def effort(log: closed_loop.TickLog, spec: closed_loop.LoopSpec) -> float:
    """Mean |Δφ| per tick of the command over the metrics window [rad], of one run: the Python
    reference of :attr:`hsa_core.apps.batch_metrics.RunSummary.effort`."""
    phi = np.asarray(log.phi_cmd)[closed_loop.metrics_window(spec, log)]
    return float(np.mean(np.abs(np.diff(phi, axis=0)))) if len(phi) > 1 else 0.0


def evaluate_population(
    kind: ControllerKind,
    population: list,
    spec: closed_loop.LoopSpec,
    inputs: closed_loop.LoopInputs,
    constants: closed_loop.LoopConstants,
    plants,
    noises: np.ndarray,
    batch: int,
) -> list[Evaluation]:
    """Every gain set on every plant (one batched loop over the product, ``batch`` runs per call, a
    short last call padded to that shape), scored by the objective."""
    n_plants = len(noises)
    pairs = [(g, p) for g in range(len(population)) for p in range(n_plants)]
    axes = closed_loop.LoopInputs(0, 0, 0, None)
    parts: list[batch_metrics.RunSummary] = []
    for lo in range(0, len(pairs), batch):
        real = min(batch, len(pairs) - lo)
        # a short chunk repeats its last run
        chunk = [pairs[lo + j] for j in np.minimum(np.arange(batch), real - 1)]
        gains = jax.tree_util.tree_map(lambda *v: np.stack(v), *[population[g] for g, _ in chunk])
        plant = np.array([p for _, p in chunk])
        params = jax.tree_util.tree_map(lambda a: a[plant], plants.params)
        logs = closed_loop.batch_rollout(
            spec, inputs._replace(plant=params, gains=gains, noise=noises[plant]), constants, axes
        )
        parts.append(
            jax.tree_util.tree_map(
                lambda a: np.asarray(a)[:real], batch_metrics.evaluate(spec, logs)
            )
        )
    m = jax.tree_util.tree_map(lambda *a: np.concatenate(a), *parts)
    values = {
        "rmse_mm": m.rmse * 1e3,
        "t_r_s": m.response_time_mean,
        "overshoot_mm": m.overshoot_mean * 1e3,
        "effort_rad": m.effort,
        "bad": (m.unstable | m.limit_cycle).astype(float),  # NaN metrics: not finite
    }
    out = []
    for g in range(len(population)):
        mine = slice(g * n_plants, (g + 1) * n_plants)
        terms = {
            key: float(np.mean(np.where(np.isfinite(v[mine]), v[mine], MISSING[key])))
            for key, v in values.items()
        }
        objective = sum(WEIGHTS[k] * terms[k] for k in WEIGHTS)
        out.append(Evaluation(objective, terms, values["rmse_mm"][mine]))
    return out


def gains_yaml(kind: ControllerKind, gains: CollocatedGains | PidGains, note: str) -> str:
    """A controller_node parameter file with the gains of ``kind`` (names as in its
    config/<material>.yaml): given after the material's file it replaces the paper's gains
    (``./run.sh --gains FILE``)."""
    suffix = "_pid" if kind is ControllerKind.PID else ""
    names = TUNED[kind] + (("gamma",) if kind is not ControllerKind.PID else ())
    params = {f"{name}{suffix}": float(getattr(gains, name)) for name in names}
    return f"# {note}\n" + yaml.safe_dump({"/**": {"ros__parameters": params}}, sort_keys=False)


def main(argv: list[str] | None = None) -> int:
    """CLI ``hsa_tune``: tune, write gains.yaml, report.json and figures, print before/after."""
    parser = cli.ArgumentParser(
        prog="hsa_tune", description="Tune a control law's gains over perturbed plants (JAX)."
    )
    parser.add_argument("--material", choices=["fpu", "epu"], default="fpu")
    parser.add_argument("--law", choices=["psatid", "psatid_gc", "pid"], default="psatid")
    parser.add_argument(
        "--plants", type=cli.positive_int, default=8, help="perturbed plants per evaluation"
    )
    parser.add_argument(
        "--range", type=float, default=0.10, dest="spread", help="± range of the perturbations"
    )
    parser.add_argument(
        "--duration", type=cli.positive, default=40.0, help="steps of the reference used [s]"
    )
    parser.add_argument("--population", type=cli.positive_int, default=10)
    parser.add_argument("--generations", type=cli.positive_int, default=6)
    parser.add_argument(
        "--batch", type=cli.positive_int, default=40, help="runs per compiled batch"
    )
    robustness.add_world_options(parser)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/tune"))
    args = parser.parse_args(argv)
    if not 0.0 <= args.spread < 1.0:
        parser.error(f"--range must be in [0, 1), got {args.spread}")
    if args.population < 2:
        parser.error("--population must be at least 2")
    if args.duration < 20.0:
        parser.error(
            "--duration must cover at least two steps (20 s): the response time needs a step change"
        )
    configure_jax()
    use_every_core()
    kind = ControllerKind(args.law)
    paper = default_gains(kind, args.material)
    disturbance = robustness.world(parser, args.disturbance, args.material, args.seed)
    profile = args.profile or load_profile(DEFAULT_PROFILE)
    reference = step_reference(args.material)
    keep = reference.t < args.duration
    reference = TimedReference(
        reference.t[keep],
        reference.p_des[keep],
        reference.name,
        min(args.duration, reference.duration),
    )
    spec, inputs, constants = closed_loop.prepare(
        profile_config(
            profile, args.material, kind.value, reference=reference, disturbance=disturbance
        )
    )
    plants = robustness.perturbed_plants(
        disturbance.plant_params(load_params(args.material)), args.plants, args.spread, args.seed
    )
    noises = closed_loop.noise_batch(disturbance, spec, plants.seeds)
    # every call runs this many: one compiled shape
    batch = min(args.batch, args.population * args.plants)
    rng = np.random.default_rng(args.seed)
    mean = np.log10([getattr(paper, n) for n in TUNED[kind]])
    std = np.full(mean.shape, LOG_SPAN)
    best: tuple[float, np.ndarray, Evaluation] | None = None
    history = []
    started = time.perf_counter()
    for generation in range(args.generations):
        samples = mean + std * rng.normal(size=(args.population, mean.size))
        if generation == 0:
            samples[0] = mean  # the paper's gains compete from the start
        population = [to_gains(kind, paper, s) for s in samples]
        scores = evaluate_population(
            kind, population, spec, inputs, constants, plants, noises, batch
        )
        order = np.argsort([e.objective for e in scores])
        if best is None or scores[order[0]].objective < best[0]:
            best = (scores[order[0]].objective, samples[order[0]], scores[order[0]])
        elite = samples[order[: max(2, round(ELITE * args.population))]]
        mean, std = elite.mean(axis=0), np.maximum(elite.std(axis=0), 0.02)
        history.append(
            {
                "generation": generation,
                "best_objective": round(best[0], 4),
                "best_gains": {n: getattr(to_gains(kind, paper, best[1]), n) for n in TUNED[kind]},
                "wall_s": round(time.perf_counter() - started, 1),
            }
        )
        print(
            f"[tune] generation {generation + 1}/{args.generations}: best J = {best[0]:.3f} "
            f"{history[-1]['best_gains']}",
            file=sys.stderr,
            flush=True,
        )
    assert best is not None
    tuned = to_gains(kind, paper, best[1])
    before, after = evaluate_population(
        kind, [paper, tuned], spec, inputs, constants, plants, noises, batch
    )
    nominal_plants = robustness.Plants(
        np.ones((1, 3)),
        jax.tree_util.tree_map(lambda a: np.asarray(a)[None], inputs.plant),
        np.array([args.seed]),
    )
    nominal = evaluate_population(
        kind,
        [paper, tuned],
        spec,
        inputs,
        constants,
        nominal_plants,
        np.asarray(inputs.noise)[None],
        batch,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    note = (
        f"hsa_tune --material {args.material} --law {args.law} --disturbance {args.disturbance} "
        f"--profile {profile.name}: median RMSE over {args.plants} "
        f"plants {np.nanmedian(before.rmse_mm):.3f} -> {np.nanmedian(after.rmse_mm):.3f} mm on "
        f"{args.duration:g} s of steps"
    )
    (args.out / "gains.yaml").write_text(gains_yaml(kind, tuned, note))
    report = {
        "material": args.material,
        "law": args.law,
        "plants": args.plants,
        "range": args.spread,
        "world": args.disturbance,
        "profile": profile.name,
        "duration_s": reference.duration,
        "weights": WEIGHTS,
        "population": args.population,
        "generations": args.generations,
        "wall_s": round(time.perf_counter() - started, 1),
        "history": history,
        "paper_gains": {n: getattr(paper, n) for n in TUNED[kind]},
        "tuned_gains": {n: getattr(tuned, n) for n in TUNED[kind]},
        "batch": {
            "paper": {
                "objective": before.objective,
                "median_rmse_mm": float(np.nanmedian(before.rmse_mm)),
                **before.terms,
            },
            "tuned": {
                "objective": after.objective,
                "median_rmse_mm": float(np.nanmedian(after.rmse_mm)),
                **after.terms,
            },
        },
        "nominal": {
            "paper_rmse_mm": float(nominal[0].rmse_mm[0]),
            "tuned_rmse_mm": float(nominal[1].rmse_mm[0]),
        },
    }
    (args.out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    with matplotlib.rc_context(plotting.STYLE):
        fig, ax = plotting.subplots(figsize=(3.6, 3.2))
        ax.boxplot(
            [before.rmse_mm[np.isfinite(before.rmse_mm)], after.rmse_mm[np.isfinite(after.rmse_mm)]]
        )
        ax.set_xticks([1, 2], ["paper gains", "tuned"])
        ax.set_ylabel("RMSE [mm]")
        ax.set_title(
            f"{plotting.law_name(kind.value)}, {args.material.upper()}, {args.plants} plants (sim)"
        )
        plotting.save_all_formats(fig, args.out / "before_after")
    print(
        f"{'':<14} {'J':>8} {'median RMSE [mm]':>17} {'t_r [s]':>8} {'bad':>5} {'nominal RMSE':>13}"
    )
    for name, e, nom in (("paper gains", before, nominal[0]), ("tuned", after, nominal[1])):
        print(
            f"{name:<14} {e.objective:8.3f} {np.nanmedian(e.rmse_mm):17.3f} "
            f"{e.terms['t_r_s']:8.3f} {e.terms['bad']:5.2f} {nom.rmse_mm[0]:13.3f}"
        )
    print(f"\ngains.yaml, report.json and figures in {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Monte-Carlo robustness of the control laws (``hsa_robustness``): N perturbed plants × laws
through the JAX loop.

Each plant is the simulated plant of the world ``--disturbance`` names (default ``calibrated``, the
material's calibrated world; ``declared``: the hand-declared one, :mod:`hsa_core.sim.disturbance`)
with its stiffnesses (Ŝ_b, Ŝ_sh, Ŝ_a, S_b,sh together), its elongation constant C_ε and its axial
rest strains σ_a,eq each scaled by an independent factor drawn uniformly from [1 − r, 1 + r]
(``--range``, default 0.10), and its own mocap noise seed. The same plants (same generator seed) are
used for every law, so the laws are compared plant by plant; the world's noise, latencies and servo
and the set-up of ``--profile`` (default the lab's) hold for every plant. Runs go through
:func:`hsa_core.sim.closed_loop.batch_rollout` (batched, split over every JAX device; the plants in
as few calls of at most ``--batch`` runs as possible, all of one size, a short last call padded to
it, so the loop compiles once) and each batch is evaluated on the devices in one call, with the
experiment's metrics and the classification below (:func:`hsa_core.apps.batch_metrics.evaluate`;
:func:`classify` is its reference in Python).

Classification per run, from the plant's noise-free EE position in the last 2 s of every step:

* **unstable**: the state left the finite numbers, or the mean error of some step's last 2 s exceeds
  ``UNSTABLE_M``;
* **limit cycle**: otherwise, the peak-to-peak of x or y over some step's last 2 s exceeds
  ``OSCILLATION_PTP_M`` (a settled run moves by the servo's tick and the noise-free plant, tenths of
  a millimetre).

Outputs in ``--out``: ``robustness.json`` (per law: the distribution of RMSE, e_ss, t_r, and the two
fractions; per run: the factors and metrics; the gains used where ``--gains LAW=FILE`` replaced the
paper's), ``robustness.csv`` and figures (``rmse_by_law``: box plots per law; ``worst_<law>``: the
worst run's x, y against the reference), PDF and PNG.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import jax
import matplotlib
import numpy as np

from hsa_core import cli
from hsa_core.analysis import plotting
from hsa_core.analysis.metrics import STEADY_STATE_WINDOW
from hsa_core.apps import batch_metrics
from hsa_core.apps.batch_metrics import OSCILLATION_PTP_M, UNSTABLE_M
from hsa_core.controller.control import (
    CollocatedGains,
    ControllerKind,
    PidGains,
    default_gains,
    load_gains,
)
from hsa_core.jaxsetup import configure_jax, use_every_core
from hsa_core.model.params import HsaParams, load_params
from hsa_core.runs.profiles import DEFAULT_PROFILE, RunProfile, load_profile
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import DEFAULT_WORLD, WORLDS, DisturbanceModel, named_world
from hsa_core.sim.experiment import ExperimentConfig, profile_config
from hsa_core.task.trajectories import TimedReference, step_reference

LAWS = ("psatid", "psatid_gc", "pid", "psatid+eei")
BOUND = "bound"
"""Not a law: each plant under perfect-model feedforward. The servos slew at full speed to the
plant's own steady-state twist for each setpoint (P-satI-D with zero gains whose model is the plant
itself), so the EE settles exactly, as fast as the servo speed limit and the plant's own dynamics
allow without overdriving the twists: the reference level for the tuning target (docs/simulation.md,
"Gain tuning")."""
BOUND_NAME = "servo-limited feedforward"


@dataclass(frozen=True)
class Worst:
    """A law's worst run: its score (RMSE [mm], inf if non-finite), record, tick log and control
    period [s]."""

    score: float
    record: dict
    log: closed_loop.TickLog
    period: float


@dataclass(frozen=True)
class Plants:
    """N perturbed plants: factors (N, 3) on stiffness, C_ε and σ_a,eq; the stacked HsaParams; noise
    seeds."""

    factors: np.ndarray
    params: HsaParams
    seeds: np.ndarray


def perturbed_plants(base: HsaParams, n: int, spread: float, seed: int) -> Plants:
    """``n`` plants around ``base`` (see the module docstring), drawn from one seeded generator."""
    rng = np.random.default_rng(seed)
    factors = rng.uniform(1.0 - spread, 1.0 + spread, size=(n, 3))
    plants = []
    for k_s, k_e, k_r in factors:
        plants.append(
            base.replace(
                S_b_hat=np.asarray(base.S_b_hat) * k_s,
                S_sh_hat=np.asarray(base.S_sh_hat) * k_s,
                S_a_hat=np.asarray(base.S_a_hat) * k_s,
                S_b_sh=np.asarray(base.S_b_sh) * k_s,
                C_eps=np.asarray(base.C_eps) * k_e,
                sigma_a_eq=np.asarray(base.sigma_a_eq) * k_r,
            )
        )
    stacked = jax.tree_util.tree_map(lambda *leaves: np.stack(leaves), *plants)
    return Plants(factors, stacked, rng.integers(0, 2**31 - 1, size=n))


def classify(spec: closed_loop.LoopSpec, log: closed_loop.TickLog) -> tuple[bool, bool]:
    """(unstable, limit cycle) of one run, from the noise-free EE position in each step's last 2 s:
    the Python reference of :attr:`hsa_core.apps.batch_metrics.RunSummary.unstable` and
    ``limit_cycle``."""
    window = closed_loop.metrics_window(spec, log)
    true = np.asarray(log.true_chiee)[window, :2]
    desired = np.asarray(log.chiee_des)[window, :2]
    if not np.all(np.isfinite(true)):
        return True, False
    changes = [
        0,
        *np.flatnonzero(np.any(np.diff(desired, axis=0) != 0.0, axis=1)) + 1,
        len(desired),
    ]
    window = round(STEADY_STATE_WINDOW / (spec.period_ms * 1e-3))
    unstable = cycling = False
    for start, stop in zip(changes[:-1], changes[1:]):
        tail = slice(max(start, stop - window), stop)
        error = np.linalg.norm(true[tail] - desired[tail], axis=1)
        unstable |= bool(np.mean(error) > UNSTABLE_M)
        cycling |= bool(np.max(np.ptp(true[tail], axis=0)) > OSCILLATION_PTP_M)
    return unstable, cycling and not unstable


def run_law(
    law: str,
    material: str,
    plants: Plants,
    disturbance: DisturbanceModel,
    batch: int,
    reference: TimedReference | None = None,
    gains: CollocatedGains | PidGains | None = None,
    profile: RunProfile | None = None,
) -> tuple[list[dict], Worst]:
    """Every plant under one law (``gains``: default the paper's) in ``disturbance``'s world,
    under the run ``profile`` (default: the lab's): one record per run (factors, metrics,
    classification) and the worst run. Under :data:`BOUND` only the plants that can reach every
    setpoint run."""
    axes = closed_loop.LoopInputs(0, None, 0, None)
    constant_axes = None
    profile = profile or load_profile(DEFAULT_PROFILE)
    if law == BOUND:
        paper = default_gains(ControllerKind.PSATID, material)
        config = profile_config(
            profile,
            material,
            ControllerKind.PSATID.value,
            gains=replace(paper, kp=0.0, ki=0.0, kd=0.0),
            reference=reference,
            disturbance=disturbance,
        )
        spec, inputs, constants, plant_index = _per_plant_constants(config, plants)
        constant_axes = closed_loop.LoopConstants(0, 0, None)
    else:
        kind, ee = _law(law)
        config = profile_config(
            profile,
            material,
            kind,
            ee_integral=ee,
            gains=gains,
            reference=reference,
            disturbance=disturbance,
        )
        spec, inputs, constants = closed_loop.prepare(config)
        plant_index = np.arange(len(plants.seeds))
    n = len(plant_index)
    # as few calls as at ``batch``, all of one size: n = 144 at 128 is 2 x 72
    size = -(-n // -(-n // batch))
    records: list[dict] = []
    worst: Worst | None = None
    for lo in range(0, n, size):
        real = min(size, n - lo)
        # a short last call repeats its last run: one shape
        pos = lo + np.minimum(np.arange(size), real - 1)
        idx = plant_index[pos]
        noise = closed_loop.noise_batch(
            disturbance, spec, plants.seeds[plant_index[lo : lo + real]]
        )
        params = jax.tree_util.tree_map(lambda a: a[idx], plants.params)
        run_constants = constants
        if (
            constant_axes is not None
        ):  # this chunk's plants as their own models, with their setpoints
            refs = jax.tree_util.tree_map(lambda a: a[pos], constants.refs)
            run_constants = constants._replace(model=params, refs=refs)
        logs = closed_loop.batch_rollout(
            spec,
            inputs._replace(plant=params, noise=noise[pos - lo]),
            run_constants,
            axes,
            constant_axes,
        )
        m = jax.tree_util.tree_map(
            lambda a: np.asarray(a)[:real], batch_metrics.evaluate(spec, logs)
        )
        for j, i in enumerate(idx[:real]):
            # NaN metrics where not finite
            records.append(
                {
                    "law": law,
                    "plant": int(i),
                    "stiffness": plants.factors[i, 0],
                    "elongation": plants.factors[i, 1],
                    "rest_strain": plants.factors[i, 2],
                    "unstable": bool(m.unstable[j]),
                    "limit_cycle": bool(m.limit_cycle[j]),
                    "rmse_mm": float(m.rmse[j] * 1e3),
                    "e_ss_mm": float(m.steady_state_error_mean[j] * 1e3),
                    "t_r_s": float(m.response_time_mean[j]),
                    "overshoot_mm": float(m.overshoot_mean[j] * 1e3),
                    "saturated": float(m.saturated_fraction[j]),
                }
            )
        scores = np.where(np.isfinite(m.rmse), m.rmse * 1e3, math.inf)
        j = int(np.argmax(scores))
        if worst is None or scores[j] > worst.score:
            one = jax.tree_util.tree_map(lambda a: np.asarray(a[j]), logs)
            worst = Worst(float(scores[j]), records[lo + j], one, spec.period_ms * 1e-3)
    assert worst is not None
    return records, worst


def _per_plant_constants(
    config: ExperimentConfig, plants: Plants
) -> tuple[closed_loop.LoopSpec, closed_loop.LoopInputs, closed_loop.LoopConstants, np.ndarray]:
    """The loop of ``config`` with each plant as the controller's model: setpoints planned on every
    plant and stacked, for the plants that can reach every setpoint (their indices, last); the
    others have no such feedforward."""
    prepared = [
        closed_loop.prepare(
            config, model=jax.tree_util.tree_map(lambda a: np.asarray(a)[i], plants.params)
        )
        for i in range(len(plants.seeds))
    ]
    full = max(len(p[2].ref_index) and int(np.max(p[2].ref_index)) for p in prepared)
    keep = np.array(
        [
            i
            for i, p in enumerate(prepared)
            if int(np.max(p[2].ref_index)) == full and p[0] == prepared[0][0]
        ]
    )
    spec, inputs, first = prepared[keep[0]]
    refs = jax.tree_util.tree_map(
        lambda *leaves: np.stack(leaves), *[prepared[i][2].refs for i in keep]
    )
    return spec, inputs, first._replace(model=plants.params, refs=refs), keep


def summary(records: list[dict]) -> dict:
    """Per law: median, quartiles and max of RMSE, e_ss and t_r; fractions unstable and
    limit-cycling."""
    out = {}
    for law in dict.fromkeys(r["law"] for r in records):
        rows = [r for r in records if r["law"] == law]
        entry: dict = {
            "runs": len(rows),
            "unstable_fraction": float(np.mean([r["unstable"] for r in rows])),
            "limit_cycle_fraction": float(np.mean([r["limit_cycle"] for r in rows])),
        }
        for key in ("rmse_mm", "e_ss_mm", "t_r_s"):
            v = np.array([r[key] for r in rows], dtype=float)
            v = v[np.isfinite(v)]
            entry[key] = (
                {
                    "median": float(np.median(v)),
                    "q25": float(np.percentile(v, 25)),
                    "q75": float(np.percentile(v, 75)),
                    "max": float(np.max(v)),
                }
                if v.size
                else {}
            )
        out[law] = entry
    return out


def figures(records: list[dict], worst: dict[str, Worst], out: Path, material: str) -> list[Path]:
    """Box plots of RMSE per law and each law's worst run."""
    laws = list(worst)
    names = [BOUND_NAME if law == BOUND else plotting.law_name(*_law(law)) for law in laws]
    with matplotlib.rc_context(plotting.STYLE):
        fig, ax = plotting.subplots(figsize=(1.6 + 1.3 * len(laws), 3.2))
        data = [
            [r["rmse_mm"] for r in records if r["law"] == law and np.isfinite(r["rmse_mm"])]
            for law in laws
        ]
        ax.boxplot(data, showfliers=True)
        ax.set_xticks(range(1, len(laws) + 1), names)
        ax.set_ylabel("RMSE [mm]")
        n = sum(1 for r in records if r["law"] == laws[0])
        ax.set_title(f"{material.upper()} steps, {n} perturbed plants (sim)")
        paths = plotting.save_all_formats(fig, out / "rmse_by_law")
        for law, name in zip(laws, names):
            w = worst[law]
            ran = np.asarray(w.log.ran)
            t = (np.arange(ran.size) - int(np.argmax(ran))) * w.period
            fig, axes = plotting.subplots(2, 1, sharex=True, figsize=(7.0, 4.2))
            for k, axis_name in enumerate(plotting.AXES_XY):
                axes[k].plot(
                    t[ran], np.asarray(w.log.chiee)[ran, k] * plotting.MM, lw=0.8, label="measured"
                )
                axes[k].plot(
                    t[ran],
                    np.asarray(w.log.chiee_des)[ran, k] * plotting.MM,
                    **plotting.SETPOINT,
                    label="reference",
                )
                axes[k].set_ylabel(f"{axis_name} [mm]")
            axes[-1].set_xlabel("t [s]")
            axes[0].legend(loc="upper right", fontsize="small")
            r = w.record
            fig.suptitle(
                f"{name}, worst of {n} plants: RMSE {r['rmse_mm']:.2f} mm (stiffness "
                f"×{r['stiffness']:.3f}, $C_\\varepsilon$ ×{r['elongation']:.3f}, "
                f"$\\sigma_{{a,eq}}$ ×{r['rest_strain']:.3f})",
                fontsize="medium",
            )
            paths += plotting.save_all_formats(fig, out / f"worst_{law.replace('+', '_')}")
    return paths


def add_world_options(parser: argparse.ArgumentParser, world: str = DEFAULT_WORLD) -> None:
    """The options that place a batched study (``hsa_robustness``, ``hsa_tune``) in a world and a
    set-up: ``--disturbance`` (a named world, :func:`hsa_core.sim.disturbance.named_world`, default
    ``world``; the perturbed plants are drawn around its plant) and ``--profile`` (a run
    profile)."""
    parser.add_argument(
        "--disturbance",
        type=cli.world_name,
        choices=WORLDS,
        default=world,
        help=f"the world (default {world}; hsa_core.sim.disturbance.named_world; a study's "
        "perturbed plants are drawn around its plant): 'calibrated' (the material's world fitted "
        "to the real runs, docs/simulation.md), 'declared', none or shear",
    )
    parser.add_argument(
        "--profile",
        type=cli.run_profile,
        default=None,
        help=f"run profile (default {DEFAULT_PROFILE}): control rate, integrators' step, velocity "
        "estimator, command latency (docs/simulation.md, 'Run profiles')",
    )


def world(parser: argparse.ArgumentParser, name: str, material: str, seed: int) -> DisturbanceModel:
    """The named world of ``material``; a world that cannot be built (e.g. no calibrated world
    for the material) is a one-line refusal through ``parser``."""
    try:
        return named_world(name, material, seed)
    except ValueError as exc:
        parser.error(f"argument --disturbance: {exc}")


def _law(law: str) -> tuple[str, bool]:
    kind, _, ext = law.partition("+")
    return kind, ext == "eei"


def _gains_arg(text: str) -> tuple[str, Path]:
    """argparse type of --gains: LAW=FILE, LAW one of LAWS, FILE a controller_node gains file (as
    hsa_tune writes)."""
    law, sep, path = text.partition("=")
    if not sep or law not in LAWS or not path:
        raise argparse.ArgumentTypeError(
            f"expected LAW=FILE with LAW one of {list(LAWS)}, got {text!r}"
        )
    try:
        load_gains(path, _law(law)[0])
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return law, Path(path)


def _laws(text: str) -> list[str]:
    """argparse type of --laws: a comma-separated list of LAWS and BOUND."""
    laws = text.split(",")
    bad = [law for law in laws if law not in (*LAWS, BOUND)]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown law(s) {bad}; choose from {[*LAWS, BOUND]}")
    return laws


def main(argv: list[str] | None = None) -> int:
    """CLI ``hsa_robustness``: run the study, print the summary table, write JSON, CSV and
    figures."""
    parser = cli.ArgumentParser(
        prog="hsa_robustness",
        description="Monte-Carlo robustness of the control laws over perturbed plants (JAX).",
    )
    parser.add_argument("--material", choices=["fpu", "epu"], default="fpu")
    parser.add_argument(
        "--laws",
        type=_laws,
        default=list(LAWS),
        help=(
            f"comma-separated, from {', '.join(LAWS)}; '{BOUND}': perfect-model feedforward at the "
            "servo speed limit, the reference level of the tuning target"
        ),
    )
    parser.add_argument(
        "--n", type=cli.positive_int, default=32, help="perturbed plants (default 32)"
    )
    parser.add_argument(
        "--range",
        type=float,
        default=0.10,
        dest="spread",
        help="relative ± range of each perturbation factor (default 0.10)",
    )
    parser.add_argument(
        "--batch",
        type=cli.positive_int,
        default=16,
        help="most runs per compiled batch (the plants are split into equal batches)",
    )
    parser.add_argument(
        "--duration",
        type=cli.positive,
        default=None,
        help="truncate the step list to this many seconds (default: all 110 s)",
    )
    parser.add_argument(
        "--gains",
        type=_gains_arg,
        action="append",
        default=[],
        metavar="LAW=FILE",
        help="that law's gains from a gains file (e.g. hsa_tune's gains.yaml; repeatable; "
        "default: the paper's)",
    )
    add_world_options(parser)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/robustness"))
    args = parser.parse_args(argv)
    gains = {law: load_gains(path, _law(law)[0]) for law, path in args.gains}
    if unused := sorted(set(gains) - set(args.laws)):
        parser.error(f"--gains for {unused}, which --laws does not run")
    if not 0.0 <= args.spread < 1.0:
        parser.error(f"--range must be in [0, 1), got {args.spread}")
    configure_jax()
    use_every_core()
    disturbance = world(parser, args.disturbance, args.material, args.seed)
    profile = args.profile or load_profile(DEFAULT_PROFILE)
    plants = perturbed_plants(
        disturbance.plant_params(load_params(args.material)), args.n, args.spread, args.seed
    )
    reference = step_reference(args.material)
    if args.duration is not None:
        keep = reference.t < args.duration
        reference = TimedReference(
            reference.t[keep],
            reference.p_des[keep],
            reference.name,
            min(args.duration, reference.duration),
        )
    args.out.mkdir(parents=True, exist_ok=True)
    records: list[dict] = []
    worst: dict[str, Worst] = {}
    started = time.perf_counter()
    for law in args.laws:
        t0 = time.perf_counter()
        rows, worst[law] = run_law(
            law, args.material, plants, disturbance, args.batch, reference, gains.get(law), profile
        )
        records += rows
        print(
            f"[robustness] {law}: {args.n} plants in {time.perf_counter() - t0:.1f} s",
            file=sys.stderr,
        )
    table = summary(records)
    keys = [
        "law",
        "plant",
        "stiffness",
        "elongation",
        "rest_strain",
        "rmse_mm",
        "e_ss_mm",
        "t_r_s",
        "overshoot_mm",
        "saturated",
        "unstable",
        "limit_cycle",
    ]
    with open(args.out / "robustness.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows({k: r[k] for k in keys} for r in records)
    (args.out / "robustness.json").write_text(
        json.dumps(
            {
                "material": args.material,
                "plants": args.n,
                "range": args.spread,
                "seed": args.seed,
                "world": args.disturbance,
                "profile": profile.name,
                "gains": {
                    law: ({"file": str(path), **dataclasses.asdict(gains[law])})
                    for law, path in args.gains
                },
                "duration_s": reference.duration,
                "devices": len(jax.devices()),
                "wall_s": round(time.perf_counter() - started, 1),
                "summary": table,
            },
            indent=2,
        )
        + "\n"
    )
    figures(records, worst, args.out, args.material)
    print(
        f"{'law':<14} {'RMSE median [mm]':>17} {'q75':>7} {'max':>7} {'e_ss med':>9} "
        f"{'t_r med':>8} {'unstable':>9} {'cycling':>8}"
    )
    for law, e in table.items():
        r, s, tr = e["rmse_mm"], e["e_ss_mm"], e["t_r_s"]
        print(
            f"{law:<14} {r.get('median', math.nan):17.3f} {r.get('q75', math.nan):7.3f} "
            f"{r.get('max', math.nan):7.3f} "
            f"{s.get('median', math.nan):9.3f} {tr.get('median', math.nan):8.3f} "
            f"{e['unstable_fraction']:9.1%} {e['limit_cycle_fraction']:8.1%}"
        )
    print(f"\nJSON, CSV and figures in {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Closed-loop calibration of the world against the real robot's step runs (no ROS).

The world's parameters that no identification fixed
(:class:`~hsa_core.sim.disturbance.DisturbanceModel` fields: the actuation latency, the servos'
speed cap and time constant, the plant's damping and shear-stiffness factors) are fitted to the
paper's reference runs (:mod:`hsa_core.runs.reference`), each replayed with its own conditions
(:func:`hsa_core.sim.experiment.replay_config`: profile, law, gains, σ_a,eq, real step instants),
on top of what the robot at rest gave: the material's static mismatch and the mocap noise bound
(:func:`base_world`).
The measure is D of :mod:`hsa_core.analysis.sim_to_real` (each step aligned at its own instant,
steps 1–10, first 9.3 s, 10 ms grid), pooled over the runs as sqrt(mean D²): one set of world
parameters for every run. A world whose runs depend on the mocap noise's realization (the
September command queue: whether a goal changes at a tick decides the driver's backlog) is scored
over several realizations of each run (``--noise-seeds``): the pooled D is then sqrt(mean over runs
and realizations of D²), not the luckiest realization's D.

* **Simulation**: the batched JAX loop (:mod:`hsa_core.sim.closed_loop`); a whole population of
  candidate worlds is one ``batch_rollout`` call per run (one compilation per run, whatever the
  candidates), so the same code runs on a GPU or on every CPU core. D is taken on the host from the
  population's logs (milliseconds).
* **Search**: derivative-free, a cross-entropy search (as :mod:`hsa_core.apps.tune`) on the
  parameters mapped to [0, 1] (a log scale for the damping factor), the latency rounded to the 1 ms
  grid, seeded and deterministic. Gradients are not used: the latency is integer, the speed cap a
  clip, D a max-free but kinked function of both; and a population is as cheap per run as one
  candidate on a vector machine.
* **Identifiability and uncertainty**: after the search each parameter is scanned alone over its
  whole range around the best world (one batched call per run): the interval where the pooled D
  stays within ``tolerance`` of the best is reported as its uncertainty. A parameter whose scan
  moves D by less than ``tolerance`` over the whole range is not identified (flat); one whose
  interval reaches a bound of its range (or the edge of the region where the run stays finite) is
  not identified (at bound): the data put its minimum outside what is physical or simulable. Either
  way the base world's value is kept, not fitted to noise or to a bound. ``tolerance`` defaults to
  0.05 mm, a sixth of the robot's own repeatability (0.32 mm RMS between two runs).
* **Refit**: the search's values of the identified parameters were found together with the
  search's values of the others, which the world does not keep; so when some parameter is not
  identified, the identified ones are searched again alone with the others at the base world's
  values, and scanned again around that world (:func:`fit_world`): the world written is the world
  fitted.
* **Leave-one-run-out**: the search (and the refit of the parameters identified on all runs)
  repeated on all runs but one, and D of the left-out run in the world it gives.
* **Held-out noise**: the world kept (and the base) scored on ``--held-out-seeds`` realizations of
  every run the fit did not see (seeds after its own): a few realizations can flatter the world
  that the search picked on them.

``python -m hsa_core.apps.calibrate`` / ``hsa_calibrate`` (:func:`main`) writes the world YAML, the
fit report (JSON) and one figure per run. ``hsa_calibrate --static --material M`` fits the static
mismatch at rest instead (:mod:`hsa_core.sysid.static_mismatch`): the fit report and the static
world YAML, and with ``--write-world`` the package's ``config/world/<material>_static.yaml``.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np
import yaml

from hsa_core import cli
from hsa_core.analysis import sim_to_real
from hsa_core.jaxsetup import configure_jax
from hsa_core.runs import reference
from hsa_core.sim import closed_loop
from hsa_core.sim.disturbance import WORLD_DIR, DisturbanceModel, rest_world
from hsa_core.sim.experiment import ExperimentConfig, replay_config
from hsa_core.sim.world import GRID_NS, servo_speed
from hsa_core.sysid import static_mismatch
from hsa_core.task.planning import Planner

TOLERANCE = 5e-5
"""[m] the pooled D a parameter must move to count as identified (module docstring)."""


@dataclass(frozen=True)
class Parameter:
    """A fitted DisturbanceModel field: its bounds [SI], whether it is searched on a log scale, its
    grid [SI] (0: none)."""

    name: str
    lower: float
    upper: float
    log: bool = False
    grid: float = 0.0

    def value(self, u: np.ndarray) -> np.ndarray:
        """[0, 1] → the parameter's value (log or linear, on its grid)."""
        u = np.clip(u, 0.0, 1.0)
        v = (
            self.lower * (self.upper / self.lower) ** u
            if self.log
            else self.lower + (self.upper - self.lower) * u
        )
        return np.round(v / self.grid) * self.grid if self.grid else v

    def unit(self, v: float) -> float:
        """The value → [0, 1]."""
        if self.log:
            return math.log(v / self.lower) / math.log(self.upper / self.lower)
        return (v - self.lower) / (self.upper - self.lower)


PARAMETERS = {
    "actuation_latency": Parameter("actuation_latency", 0.0, 0.25, grid=GRID_NS * 1e-9),
    "servo_time_constant": Parameter("servo_time_constant", 0.0, 0.15),
    "servo_max_speed": Parameter("servo_max_speed", 1.5, 55.0 * 2.0 * math.pi / 60.0),
    "damping_scale": Parameter("damping_scale", 0.2, 20.0, log=True),
    "shear_scale": Parameter("shear_scale", 0.25, 2.0, log=True),
}
"""What may be fitted, with physical bounds: the latency at most 0.25 s (the longest onset of a
real step), the speed
cap at most the MX-28's no-load speed (e-Manual), the damping
within two decades of the hand-tuned constants, the plant's shear stiffness within a factor 4 below
and 2 above the
identified one (the constant-strain model captures the shear poorly, experiments.md §6)."""


@dataclass
class PreparedRun:
    """A reference run ready for the batched loop: its replay config, the loop, the plant model and
    the robot."""

    bag: str
    config: ExperimentConfig
    spec: closed_loop.LoopSpec
    inputs: closed_loop.LoopInputs
    constants: closed_loop.LoopConstants
    robot: sim_to_real.StepRun
    note: str
    steps: tuple[int, ...]  # the steps compared
    horizon: float = sim_to_real.HORIZON  # [s] of each step compared


def prepare_run(
    bag: str, duration: float | None = None, world: DisturbanceModel | None = None
) -> PreparedRun:
    """The run ``bag`` replayed with its own conditions (:func:`replay_config`) in ``world``
    (default: the declared one), whose mocap noise and latency every candidate shares; with its
    logbook σ_a,eq unless the planner cannot reach every setpoint with it (then the material's
    nominal, said in ``note``). ``duration`` cuts the run (a quick check: the steps it holds whole
    are compared)."""
    real = reference.load_run(bag)
    config = replay_config(real, disturbance=world or DisturbanceModel())
    note = (
        "logbook sigma_a_eq"
        if config.plant_sigma_a_eq is None
        else "logbook sigma_a_eq in the plant, nominal in the controller's model (PID: no plan)"
    )
    planner = Planner(config.model(), config.planner)
    if not all(planner.plan(p).success for p in config.reference.p_des):
        config, note = (
            dataclasses.replace(config, sigma_a_eq=None),
            "nominal sigma_a_eq (the logbook's has no plan for every setpoint)",
        )
    if duration is not None:
        ref = config.reference
        keep = ref.t < duration
        config = dataclasses.replace(
            config, reference=type(ref)(ref.t[keep], ref.p_des[keep], ref.name, duration)
        )
    spec, inputs, constants = closed_loop.prepare(config)
    end = config.reference.duration
    robot = sim_to_real.StepRun(real.t, real.p, real.p_des, end)
    steps = sim_to_real.STEPS
    if duration is not None:
        whole = int(np.sum(real.step_instants + sim_to_real.HORIZON + 0.1 < duration))
        if whole < 1:
            raise ValueError(f"{bag}: {duration} s hold no whole step to compare")
        steps = tuple(range(1, min(whole, len(sim_to_real.STEPS)) + 1))
    return PreparedRun(bag, config, spec, inputs, constants, robot, note, steps)


def candidate_inputs(run: PreparedRun, worlds: list[DisturbanceModel]) -> closed_loop.LoopInputs:
    """The loop inputs of ``run`` in each of ``worlds`` (stacked; the noise realization and gains
    of the run shared, whatever a candidate's seed: a world whose mocap noise or latency differs
    from the run's is refused)."""
    shared = ("pose_noise_std", "measurement_latency")
    own = run.config.base_world()
    worlds = [dataclasses.replace(w, seed=own.seed) for w in worlds]
    for w in worlds:
        if any(getattr(w, n) != getattr(own, n) for n in shared):
            raise ValueError(
                f"a candidate world must keep the run's {', '.join(shared)} "
                f"(prepare_run's world): {[getattr(w, n) for n in shared]}"
            )
    model = run.config.model()
    plant_model = model.replace(m_pl=run.config.payload) if run.config.payload else model
    worlds = [dataclasses.replace(run.config, disturbance=w).world() for w in worlds]
    lat = [round(w.actuation_latency * 1e3) for w in worlds]
    if any(abs(w.actuation_latency * 1e3 - v) > 1e-9 for w, v in zip(worlds, lat)) or max(
        lat
    ) > _max_latency_ms(run):
        raise ValueError(
            f"actuation latencies must be whole ms up to {_max_latency_ms(run)} ms, got {lat}"
        )
    plants = [w.plant_params(plant_model) for w in worlds]
    return run.inputs._replace(
        plant=jax.tree_util.tree_map(lambda *v: np.stack([np.asarray(a) for a in v]), *plants),
        servo_speed=np.array([servo_speed(w.servo_max_speed) for w in worlds]),
        servo_lag=np.array([w.servo_time_constant for w in worlds]),
        actuation_latency_ms=np.array(lat),
    )


def _max_latency_ms(run: PreparedRun) -> int:
    """The longest actuation latency a candidate of ``run`` may have [ms], the run's command latency
    included (one loop compilation covers them all)."""
    return round((PARAMETERS["actuation_latency"].upper + run.config.command_latency) * 1e3)


def simulate(run: PreparedRun, worlds: list[DisturbanceModel]) -> list[sim_to_real.StepRun]:
    """One batched call: the run in each world, as StepRuns (measured EE position at the ticks of
    the metrics; NaN throughout where the plant's true pose is not finite: a diverged plant, which
    the controller's estimator would hide behind its last finite state)."""
    axes = closed_loop.LoopInputs(0, None, None, 0, 0, 0)
    spec = dataclasses.replace(
        run.spec,
        goal_slots=closed_loop.goal_slots_for(
            _max_latency_ms(run), run.spec.period_ms, run.spec.transaction_ms
        ),
    )
    logs = closed_loop.batch_rollout(spec, candidate_inputs(run, worlds), run.constants, axes)
    ran = np.asarray(logs.ran)
    chiee, chiee_des = np.asarray(logs.chiee), np.asarray(logs.chiee_des)
    true_chiee = np.asarray(logs.true_chiee)
    n, period = run.spec.n_eval, run.spec.period_ms * 1e-3
    out = []
    for i in range(len(worlds)):
        first = int(np.argmax(ran[i]))
        window = slice(first, first + n)
        t = np.arange(len(chiee[i, window])) * period
        p = chiee[i, window, :2]
        p = p if np.isfinite(true_chiee[i, window]).all() else np.full_like(p, np.nan)
        out.append(sim_to_real.StepRun(t, p, chiee_des[i, window, :2], n * period))
    return out


def deviations(run: PreparedRun, worlds: list[DisturbanceModel]) -> np.ndarray:
    """(len(worlds),) [m] D of the run in each world (inf where the sim lacks a step or is not
    finite)."""
    return np.array([deviation(run, sim) for sim in simulate(run, worlds)])


def deviation(run: PreparedRun, sim: sim_to_real.StepRun) -> float:
    """[m] D of one simulation of ``run`` (inf where it lacks a step or is not finite)."""
    try:
        d = sim_to_real.deviation(sim, run.robot, run.steps, run.horizon)
    except ValueError:
        return math.inf
    return d if math.isfinite(d) else math.inf


def base_world(bags: tuple[str, ...]) -> tuple[DisturbanceModel, str]:
    """The world a fit of the runs ``bags`` starts from and keeps what it does not fit of, and its
    name: the rest world of the runs' material (its adopted static mismatch and the mocap noise
    bound, both from the robot at rest) when they share one, else the declared world."""
    materials = {reference.load_run(b).conditions.material for b in bags}
    if len(materials) == 1:
        material = materials.pop()
        name = f"{material} rest world (config/world/{material}_static.yaml, mocap_noise.yaml)"
        return rest_world(material), name
    return DisturbanceModel(), "declared (the runs are of several materials)"


def pooled(d: np.ndarray) -> np.ndarray:
    """sqrt(mean over runs of D²): (runs, candidates) → (candidates,)."""
    return np.sqrt(np.mean(np.asarray(d) ** 2, axis=0))


def worlds_of(
    base: DisturbanceModel, names: tuple[str, ...], values: np.ndarray
) -> list[DisturbanceModel]:
    """``base`` with the fields ``names`` set to each row of ``values``."""
    return [
        dataclasses.replace(base, **{n: float(v) for n, v in zip(names, row)})
        for row in np.atleast_2d(values)
    ]


@dataclass
class SearchResult:
    """Best values (name → SI), the pooled D of the best [m], the history of the best per
    generation [m]."""

    best: dict[str, float]
    objective: float
    history: list[float]
    evaluations: int


def search(
    runs: list[PreparedRun],
    names: tuple[str, ...],
    base: DisturbanceModel,
    *,
    population: int = 16,
    generations: int = 8,
    elite: int = 4,
    seed: int = 0,
) -> SearchResult:
    """Cross-entropy search of ``names`` (keys of PARAMETERS) minimising the pooled D over
    ``runs``."""
    params = [PARAMETERS[n] for n in names]
    rng = np.random.default_rng(seed)
    mean = np.array([p.unit(getattr(base, p.name)) for p in params]).clip(0.0, 1.0)
    std = np.full(len(params), 0.3)
    best_u, best_f, history, evaluations = mean.copy(), math.inf, [], 0
    for _ in range(generations):
        u = np.vstack([best_u, rng.normal(mean, std, (population - 1, len(params)))]).clip(0.0, 1.0)
        values = np.stack([p.value(u[:, i]) for i, p in enumerate(params)], axis=1)
        f = pooled([deviations(r, worlds_of(base, names, values)) for r in runs])
        evaluations += population * len(runs)
        order = np.argsort(f)
        if f[order[0]] < best_f:
            best_f, best_u = float(f[order[0]]), u[order[0]].copy()
        history.append(best_f)
        print(
            f"generation {len(history)}: best pooled D {best_f * 1e3:.3f} mm",
            file=sys.stderr,
            flush=True,
        )
        mean = u[order[:elite]].mean(axis=0)
        std = np.maximum(u[order[:elite]].std(axis=0), 0.02)
    best = {p.name: float(p.value(best_u[i])) for i, p in enumerate(params)}
    return SearchResult(best, best_f, history, evaluations)


def scan(
    runs: list[PreparedRun], name: str, world: DisturbanceModel, points: int = 9
) -> tuple[np.ndarray, np.ndarray]:
    """Parameter ``name`` alone over its whole range around ``world``: ``points`` − 1 values evenly
    spaced from its lower to its upper bound (both included; at least the two) and the world's own,
    sorted: (values, pooled D [m]), one call per run."""
    p = PARAMETERS[name]
    grid = p.value(np.linspace(0.0, 1.0, max(points - 1, 2)))
    values = np.sort(np.append(grid, getattr(world, name)))
    d = pooled([deviations(r, worlds_of(world, (name,), values[:, None])) for r in runs])
    return values, d


class Identification(enum.Enum):
    """What a scan says of a parameter (:func:`identification`)."""

    IDENTIFIED = "identified"
    FLAT = "not identified (flat)"
    AT_BOUND = "not identified (at bound)"


def identification(
    values: np.ndarray, d: np.ndarray, best: float, tolerance: float = TOLERANCE
) -> dict:
    """From a scan (``values`` sorted, the parameter's bounds first and last): the interval where
    D ≤ min + tolerance, and the status: flat (D moves by less than tolerance over the range), at
    bound (the interval reaches the first or the last value where D is finite: a bound of the
    search, or the edge of the region where the run is finite, so the data put the minimum outside
    the range), else identified."""
    finite = np.isfinite(d)
    inside = finite & (d <= np.min(d[finite]) + tolerance)
    ends = np.flatnonzero(finite)[[0, -1]]
    if np.max(d[finite]) - np.min(d[finite]) < tolerance:
        status = Identification.FLAT
    elif inside[ends].any():
        status = Identification.AT_BOUND
    else:
        status = Identification.IDENTIFIED
    return {
        "identified": status is Identification.IDENTIFIED,
        "status": status.value,
        "interval": [float(values[inside].min()), float(values[inside].max())],
        "best": best,
        "scan": {"values": values.tolist(), "D_mm": (d * 1e3).round(4).tolist()},
    }


@dataclass
class WorldFit:
    """A fit's outcome: the search over every fitted parameter, each one's scan, the refit of the
    identified ones alone (None when every fitted parameter or none is identified), and the world
    kept."""

    search: SearchResult
    identification: dict[str, dict]
    refit: SearchResult | None
    kept: dict[str, float]

    @property
    def identified(self) -> tuple[str, ...]:
        """The fitted parameters the data identify."""
        return tuple(n for n, i in self.identification.items() if i["identified"])


def refit(
    runs: list[PreparedRun],
    first: SearchResult,
    identified: tuple[str, ...],
    base: DisturbanceModel,
    **budget: int,
) -> SearchResult:
    """The parameters ``identified`` searched again alone over ``runs``, starting from ``first``'s
    values, with every other field at ``base``'s (``budget``: :func:`search`'s keywords)."""
    start = dataclasses.replace(base, **{n: first.best[n] for n in identified})
    return search(runs, identified, start, **budget)


def fit_world(
    runs: list[PreparedRun],
    names: tuple[str, ...],
    base: DisturbanceModel,
    *,
    population: int = 16,
    generations: int = 8,
    seed: int = 0,
    scan_points: int = 9,
    tolerance: float = TOLERANCE,
) -> WorldFit:
    """Search ``names`` on ``base``, scan each around the best world (:func:`identification`), and
    keep the identified ones at values fitted with the others at ``base``'s: when some parameter is
    not identified, the identified ones are searched again alone (:func:`refit`, same budget and
    seed) and scanned again around the world kept, whose scans are then the evidence. A parameter
    the second scan no longer identifies keeps ``base``'s value too."""
    budget = {"population": population, "generations": generations, "seed": seed}

    def scans(world: DisturbanceModel, best: dict[str, float]) -> dict[str, dict]:
        return {
            n: identification(*scan(runs, n, world, scan_points), best[n], tolerance) for n in best
        }

    first = search(runs, names, base, **budget)
    ident = scans(dataclasses.replace(base, **first.best), first.best)
    identified = tuple(n for n in names if ident[n]["identified"])
    second = None
    if identified and len(identified) < len(names):
        second = refit(runs, first, identified, base, **budget)
        ident |= scans(dataclasses.replace(base, **second.best), second.best)
    best = second.best if second else first.best
    kept = {n: best[n] if ident[n]["identified"] else getattr(base, n) for n in names}
    return WorldFit(first, ident, second, kept)


def held_out_noise(
    bags: tuple[str, ...],
    seeds: range,
    duration: float | None,
    base: DisturbanceModel,
    world: DisturbanceModel,
) -> dict:
    """The base and the kept ``world`` scored on noise realizations the fit did not see
    (``seeds``): the pooled D over every run and realization, and each run's D per realization
    [mm]."""
    per_run, every = {}, []
    for bag in bags:
        realizations = [
            prepare_run(bag, duration, dataclasses.replace(base, seed=k)) for k in seeds
        ]
        d = np.array(
            [[deviation(r, sim) for sim in simulate(r, [base, world])] for r in realizations]
        )
        every.append(d)
        per_run[bag] = {
            label: {
                "D_mm": round(float(pooled(d[:, i : i + 1])[0]) * 1e3, 3),
                "D_per_noise_seed_mm": (d[:, i] * 1e3).round(3).tolist(),
            }
            for i, label in enumerate(("base", "calibrated"))
        }
    total = pooled(np.concatenate(every))
    return {
        "seeds": list(seeds),
        "D_mm": {
            "base": round(float(total[0]) * 1e3, 4),
            "calibrated": round(float(total[1]) * 1e3, 4),
        },
        "per_run": per_run,
    }


def world_document(report: dict) -> dict:
    """The world YAML of a fit report: each parameter's value (the fitted one if identified, else
    the base world's), the fit's value (the refit's for a parameter it refitted, else the
    search's), the status, interval and scan (the evidence), and D per run in the base and the
    calibrated world, left out and on held-out noise realizations."""
    held = report.get("held_out_noise")
    return {
        "what": "DisturbanceModel fields fitted by hsa_calibrate to the paper's real step runs",
        "runs": report["runs"],
        "conditions": {
            bag: {
                "profile": row["profile"],
                "control_period_ms": row["control_period_ms"],
                "command_latency_ms": row["command_latency_ms"],
                "command_queue": row["command_queue"],
                "note": "each run's command latency adds to actuation_latency, its command queue "
                "carries its goals (run_disturbance)",
            }
            for bag, row in report["per_run"].items()
        },
        "objective": f"{report['objective']}: {report['kept_objective_mm']} mm (the world kept)",
        "noise_seeds": report["noise_seeds"],
        "base": report["base"],
        "parameters": {
            n: {
                "value": report["kept"][n],
                "fitted": (report["refit"] or {"best": {}})["best"].get(n, report["best"][n]),
                "identified": ident["identified"],
                "status": ident["status"],
                "interval": ident["interval"],
                "uncertainty": f"pooled D within {TOLERANCE * 1e3:.2f} mm of its minimum",
                "scan": ident["scan"],
            }
            for n, ident in report["identification"].items()
        },
        "evidence_D_mm": {
            bag: {"base": row["base"]["D_mm"], "calibrated": row["calibrated"]["D_mm"]}
            for bag, row in report["per_run"].items()
        },
        "leave_one_run_out_D_mm": {
            bag: row["D_left_out_mm"] for bag, row in report["leave_one_run_out"].items()
        },
        "held_out_noise_D_mm": None
        if held is None
        else {
            "seeds": held["seeds"],
            "pooled": held["D_mm"]["calibrated"],
            **{bag: row["calibrated"]["D_mm"] for bag, row in held["per_run"].items()},
        },
    }


def _figure(run: PreparedRun, sims: dict[str, sim_to_real.StepRun], path: Path) -> None:
    """x and y over time: the robot against each simulated world (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(12, 6), sharex=True)
    shift = run.robot.step_starts[0] - list(sims.values())[0].step_starts[0]  # align the first step
    for i, axis in enumerate("xy"):
        ax = axes[i]
        ax.plot(run.robot.t, run.robot.p_des[:, i] * 1e3, color="0.6", lw=0.8, label="setpoint")
        ax.plot(run.robot.t, run.robot.p[:, i] * 1e3, color="k", lw=1.0, label="robot")
        for (label, sim), color in zip(sims.items(), ("tab:red", "tab:blue")):
            ax.plot(sim.t + shift, sim.p[:, i] * 1e3, color=color, lw=0.8, label=label)
        ax.set_ylabel(f"{axis} [mm]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(
        f"{run.bag} ({run.config.material}, {run.config.controller}): robot vs simulation"
    )
    axes[1].set_xlabel("t [s] (the robot's time; the sim aligned at the first step)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _names(text: str) -> tuple[str, ...]:
    """argparse type of --fit: comma-separated keys of PARAMETERS."""
    names = tuple(text.split(","))
    bad = [n for n in names if n not in PARAMETERS]
    if bad or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"unknown or repeated parameter(s) {bad or names}; choose from {', '.join(PARAMETERS)}"
        )
    return names


def _runs(text: str) -> tuple[str, ...]:
    """argparse type of --runs: comma-separated bag names of the packaged reference runs."""
    names = tuple(text.split(","))
    bad = [n for n in names if n not in reference.run_names()]
    if bad:
        raise argparse.ArgumentTypeError(
            f"unknown reference run(s) {bad}; known: {', '.join(reference.run_names())}"
        )
    return names


STATIC_ONLY = ("material", "write_world")
"""Options of ``--static`` alone."""
CLOSED_LOOP_ONLY = (
    "fit",
    "runs",
    "population",
    "generations",
    "scan_points",
    "duration",
    "no_loo",
    "seed",
    "noise_seeds",
    "held_out_seeds",
    "world",
)
"""Options of the closed-loop fit alone."""


def _check_mode(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (exit 2) the options of the other mode and ``--static`` without ``--material``."""
    if args.static and args.material is None:
        parser.error("argument --material: required with --static")
    wrong, why = (CLOSED_LOOP_ONLY, "not with") if args.static else (STATIC_ONLY, "only with")
    for dest in wrong:
        if getattr(args, dest) != parser.get_default(dest):
            parser.error(f"argument --{dest.replace('_', '-')}: {why} --static")


def static_main(material: str, out: Path, write_world: bool) -> int:
    """``--static``: fit the static mismatch of ``material`` at rest; write the fit report
    ``<out>/<material>_static_report.json`` and the world ``<out>/<material>_static.yaml``, and
    with ``write_world`` the package's ``config/world/<material>_static.yaml``."""
    started = time.perf_counter()
    bags = static_mismatch.material_runs(material)
    analysis = static_mismatch.static_analysis(material, bags)
    source = f"hsa_calibrate --static --material {material} (hsa_core.sysid.static_mismatch)"
    world = static_mismatch.world_document(material, analysis, source)
    report = {
        "what": "the static plant/model mismatch fitted to the real runs' end-of-step pairs",
        "material": material,
        "runs": list(bags),
        "window_s": static_mismatch.WINDOW,
        "field_set": static_mismatch.CHOSEN[material],
        **analysis,
        "world": world,
        "wall_s": round(time.perf_counter() - started, 1),
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{material}_static_report.json").write_text(json.dumps(report, indent=1) + "\n")
    text = yaml.safe_dump(world, sort_keys=False)
    for path in [out] + ([WORLD_DIR] if write_world else []):
        (path / f"{material}_static.yaml").write_text(text)
    chosen = analysis["fits"][static_mismatch.CHOSEN[material]]["per_run"]
    for bag in bags:
        before, after = analysis["declared_world"][bag]["rms_mm"], chosen[bag]["rms_mm"]
        print(f"{bag}: static residual RMS {before:.2f} -> {after:.2f} mm")
    for name, field in world["fields"].items():
        std = f" ± {field['std']:.2g}" if "std" in field else ""
        print(f"{name}: {field['value']:.4g}{std} ({field['status'].split(' (')[0]})")
    written = " and the package's world" if write_world else ""
    print(f"report in {out / f'{material}_static_report.json'}{written}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """CLI: fit, scan, leave-one-run-out; write the world YAML, the report JSON and a figure per
    run."""
    parser = cli.ArgumentParser(
        prog="hsa_calibrate",
        description="Fit the simulated world to the paper's real step runs (batched JAX loop).",
    )
    parser.add_argument(
        "--fit",
        type=_names,
        default=tuple(PARAMETERS),
        help=f"parameters to fit, comma-separated (default: all): {', '.join(PARAMETERS)}",
    )
    parser.add_argument(
        "--runs", type=_runs, default=reference.run_names(), help="reference runs (default: all)"
    )
    parser.add_argument("--population", type=cli.positive_int, default=16)
    parser.add_argument("--generations", type=cli.positive_int, default=6)
    parser.add_argument("--scan-points", type=cli.positive_int, default=7)
    parser.add_argument(
        "--duration",
        type=cli.positive,
        default=None,
        help="[s] cut every run (a quick check; D then needs the steps it compares)",
    )
    parser.add_argument("--no-loo", action="store_true", help="skip leave-one-run-out")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--noise-seeds",
        type=cli.positive_int,
        default=1,
        help="mocap noise realizations of each run (seeds 0..N-1) the pooled D is taken over",
    )
    parser.add_argument(
        "--held-out-seeds",
        type=cli.non_negative_int,
        default=4,
        help="score the world kept on M realizations the fit did not see (seeds N..N+M-1; 0: none)",
    )
    parser.add_argument("--out", type=Path, default=Path("out/calibrate"))
    parser.add_argument("--world", type=Path, default=None, help="also write the world YAML here")
    parser.add_argument(
        "--static",
        action="store_true",
        help="fit the static mismatch at rest instead (hsa_core.sysid.static_mismatch)",
    )
    parser.add_argument(
        "--material",
        choices=tuple(static_mismatch.CHOSEN),
        default=None,
        help="--static: the material fitted",
    )
    parser.add_argument(
        "--write-world",
        action="store_true",
        help="--static: also write the package's config/world/<material>_static.yaml",
    )
    args = parser.parse_args(argv)
    _check_mode(parser, args)
    if args.population < 2:
        parser.error("argument --population: must be >= 2")
    configure_jax()
    if args.static:
        return static_main(args.material, args.out, args.write_world)
    from hsa_core.jaxsetup import use_every_core

    use_every_core()
    started = time.perf_counter()
    base, base_name = base_world(args.runs)
    try:
        runs = [
            prepare_run(bag, args.duration, dataclasses.replace(base, seed=k))
            for bag in args.runs
            for k in range(args.noise_seeds)
        ]
    except ValueError as err:
        parser.error(f"argument --duration: {err}")

    fit = fit_world(
        runs,
        args.fit,
        base,
        population=args.population,
        generations=args.generations,
        seed=args.seed,
        scan_points=args.scan_points,
    )
    world = dataclasses.replace(base, **fit.kept)
    loo = {}
    if not args.no_loo and len(args.runs) > 2 and fit.identified:
        budget = {"population": args.population, "generations": args.generations, "seed": args.seed}
        for bag in args.runs:
            rest = [r for r in runs if r.bag != bag]
            sub = search(rest, args.fit, base, **budget)
            if fit.refit is not None:
                sub = refit(rest, sub, fit.identified, base, **budget)
            d = [
                deviations(r, [dataclasses.replace(base, **sub.best)])[0]
                for r in runs
                if r.bag == bag
            ]
            loo[bag] = {
                "fitted_on_others": sub.best,
                "D_left_out_mm": round(float(pooled(np.array(d)[:, None])[0]) * 1e3, 3),
            }
    args.out.mkdir(parents=True, exist_ok=True)
    per_run, kept_d = {}, []
    for bag in args.runs:
        realizations = [r for r in runs if r.bag == bag]
        sims = [simulate(r, [base, world]) for r in realizations]  # (seeds, 2)
        d = np.array([[deviation(r, sim) for sim in pair] for r, pair in zip(realizations, sims)])
        kept_d.extend(d[:, 1])
        r, (before, after) = realizations[0], sims[0]  # other measures, figure: the first
        rows = {}
        for label, sim in (("base", before), ("calibrated", after)):
            c = sim_to_real.compare(sim, r.robot, r.steps)
            d_step = sim_to_real.step_deviations(sim, r.robot, r.steps)
            column = d[:, 0 if label == "base" else 1]
            rows[label] = {
                "D_mm": round(float(pooled(column[:, None])[0]) * 1e3, 3),
                "D_per_noise_seed_mm": (column * 1e3).round(3).tolist(),
                "D_per_step_mm": (d_step * 1e3).round(3).tolist(),
                "x_p2p_last2s_max_mm": [round(v * 1e3, 3) for v in c.x_peak_to_peak],
                "rise_time_median_relative_difference": round(c.rise_time_difference, 3),
                "onset_median_s": [
                    round(float(np.nanmedian(sim_to_real.onset_times(x, r.steps))), 3)
                    for x in (sim, r.robot)
                ],
                "rmse_mm": [round(v * 1e3, 3) for v in c.rmse],
            }
        per_run[bag] = {
            "note": r.note,
            "profile": r.config.profile,
            "control_period_ms": round(1e3 / r.config.rate),
            "command_latency_ms": round(r.config.command_latency * 1e3),
            "command_queue": {
                "depth": r.config.command_queue[0],
                "transaction_ms": round(r.config.command_queue[1] * 1e3),
            },
            **rows,
        }
        _figure(r, {"base world": before, "calibrated world": after}, args.out / f"{r.bag}.png")
    seeds = range(args.noise_seeds, args.noise_seeds + args.held_out_seeds)
    held = held_out_noise(args.runs, seeds, args.duration, base, world) if seeds else None
    wall = time.perf_counter() - started
    report = {
        "fit": list(args.fit),
        "runs": list(args.runs),
        "objective": "sqrt(mean over runs and noise realizations of D^2)",
        "noise_seeds": args.noise_seeds,
        "base": base_name,
        "best": fit.search.best,
        "objective_mm": round(fit.search.objective * 1e3, 4),
        "history_mm": [round(h * 1e3, 4) for h in fit.search.history],
        "evaluations": fit.search.evaluations,
        "identification": fit.identification,
        "refit": None
        if fit.refit is None
        else {
            "fit": list(fit.refit.best),
            "best": fit.refit.best,
            "objective_mm": round(fit.refit.objective * 1e3, 4),
            "history_mm": [round(h * 1e3, 4) for h in fit.refit.history],
            "evaluations": fit.refit.evaluations,
        },
        "kept": fit.kept,
        "kept_objective_mm": round(float(pooled(np.array(kept_d)[:, None])[0]) * 1e3, 4),
        "per_run": per_run,
        "per_run_note": "D_mm over every noise realization (sqrt of the mean of D^2); the other "
        "measures and the figure: noise seed 0",
        "leave_one_run_out": loo,
        "held_out_noise": held,
        "held_out_noise_note": "the base and the kept world on noise realizations the fit did not "
        "see (D_mm: sqrt of the mean of D^2 over every run and realization)",
        "wall_s": round(wall, 1),
        "devices": len(jax.devices()),
        "backend": jax.default_backend(),
    }
    (args.out / "report.json").write_text(json.dumps(report, indent=1) + "\n")
    world_doc = world_document(report)
    for path in [args.out / "world.yaml"] + ([args.world] if args.world else []):
        path.write_text(yaml.safe_dump(world_doc, sort_keys=False))
    for bag, row in per_run.items():
        print(f"{bag}: D {row['base']['D_mm']:.2f} -> {row['calibrated']['D_mm']:.2f} mm")
    if held:
        print(
            f"on {len(held['seeds'])} noise realizations the fit did not see: pooled D "
            f"{held['D_mm']['base']:.3f} -> {held['D_mm']['calibrated']:.3f} mm"
        )
    print(f"kept {fit.kept} in {wall:.0f} s; report in {args.out / 'report.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

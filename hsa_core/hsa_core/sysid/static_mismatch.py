"""The world's static plant/model mismatch fitted to the real robot at rest.

At the end of every step of a reference run (:mod:`hsa_core.runs.reference`) the robot is at rest:
the commanded φ (``<bag>_phi.csv``, mean over the step's last :data:`WINDOW` seconds) and the
measured end-effector pose (x, y from ``<bag>_pee_100Hz.csv``, the orientation θ from the
estimated q of ``<bag>_q.csv`` through the forward kinematics; same window) are a static pair of
the real plant's map φ → pose (one per step, step 0 included). The model's pair is the static
equilibrium at that φ (:func:`hsa_core.task.planning.static_equilibrium` from rest, then the
end-effector pose) of the plant ``DisturbanceModel(...).plant_params(model)``, the model carrying
the run's logbook σ_a,eq. The residual is (x, y, l·θ) [m] (l the rods' length): without θ the two
components of p cannot tell the plant's shear from its actuation.

* :func:`fit`: least squares (scipy, finite differences, bounds :data:`BOUNDS`) of a few
  DisturbanceModel fields on the pairs of some runs; standard errors from the Jacobian
  (Gauss–Newton, residual variance).
* :func:`static_analysis`: every field set of :data:`FIELD_SETS` on a material's runs, with
  leave-one-run-out where there are several, the stiffness factor profiled, and the approach
  direction of the chosen set (:func:`approach_direction`).
* :func:`world_document`: the fitted static world of a material (each field's value in force,
  its standard error, leave-one-run-out range and :class:`FieldStatus`), the document that
  :func:`hsa_core.sim.disturbance.calibrated_world` reads from
  ``config/world/<material>_static.yaml``.

``hsa_calibrate --static`` (:mod:`hsa_core.apps.calibrate`) runs it; docs/simulation.md, "The
static mismatch, fitted at rest", holds the method and the figures.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from hsa_core.model import kinematics
from hsa_core.model.params import HsaParams, load_params
from hsa_core.runs.reference import load_run, run_names
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.task.planning import static_equilibrium

WINDOW = 2.0
"""[s] the end of a step taken as at rest (as the step tables' last 2 s)."""
ACTUATION = ("elongation_scale", "rest_strain_offset", "rest_strain_difference")
SHEAR = ("shear_scale", "shear_strain_offset")
FIELD_SETS = {
    "declared knobs": ("stiffness_scale", "elongation_scale", "rest_strain_offset"),
    "actuation": ACTUATION,
    "actuation + shear stiffness": (*ACTUATION, "shear_scale"),
    "actuation + shear": (*ACTUATION, *SHEAR),
    "actuation + shear + stiffness": (*ACTUATION, *SHEAR, "stiffness_scale"),
    "actuation + shear offset": (*ACTUATION, "shear_strain_offset"),
}
"""Field sets fitted (stiffness_scale 1 where it is not fitted: the identified parameter set)."""
CHOSEN = {"fpu": "actuation + shear", "epu": "actuation + shear offset"}
"""The field set of each material's world: every field its pairs identify."""
ADOPTED = {
    "fpu": (
        True,
        "fitted on the three FPU runs at rest; leave-one-run-out holds (docs/simulation.md)",
    ),
    "epu": (
        False,
        "evidence only: fitted to one run, which issue 20 does not accept as a calibration",
    ),
}
"""Whether each material's static world is adopted (calibrated_world reads it), and why."""
ZERO_DEFAULT = ("rest_strain_offset", "rest_strain_difference", "shear_strain_offset")
"""Fields whose default is 0: one within two standard errors of 0 is not identified."""
START = {
    "stiffness_scale": 1.05,
    "elongation_scale": 0.97,
    "rest_strain_offset": 0.005,
    "rest_strain_difference": 0.0,
    "shear_scale": 1.0,
    "shear_strain_offset": 0.0,
}
"""Where the least squares starts (the declared world, the new fields at their default)."""
BOUNDS = {
    "stiffness_scale": (0.2, 10.0),
    "elongation_scale": (0.5, 1.5),
    "rest_strain_offset": (-0.1, 0.1),
    "rest_strain_difference": (-0.1, 0.1),
    "shear_scale": (0.1, 10.0),
    "shear_strain_offset": (-0.1, 0.1),
}
"""Where the least squares may look (wide: a value at a bound is reported as not identified)."""
STIFFNESS_FACTORS = (0.8, 0.9, 1.0, 1.1, 1.2, 1.5, 2.0)
"""The stiffness factors of the profile (the chosen set refitted at each)."""


class FieldStatus(enum.Enum):
    """What the fit says of a field of the static world (the ``status`` of world_document)."""

    IDENTIFIED = "identified"
    WITHIN_NOISE_OF_ZERO = "not identified: within two standard errors of 0"
    AT_BOUND = "not identified: at the bound of its range"
    PROFILE_FLAT = "not identified"


@dataclass(frozen=True)
class StaticPairs:
    """A run's pairs at the end of its steps: φ (n, 2) [rad], p and p_des (n, 2) [m], θ (n,) [rad],
    the step's move in x (n,) [m] (NaN for step 0), the window's φ peak-to-peak (n, 2) [rad]."""

    phi: np.ndarray
    p: np.ndarray
    p_des: np.ndarray
    theta: np.ndarray
    move_x: np.ndarray
    phi_spread: np.ndarray


def material_runs(material: str) -> tuple[str, ...]:
    """The packaged reference runs of ``material``, oldest first (ValueError: none)."""
    bags = tuple(b for b in run_names() if load_run(b).conditions.material == material)
    if not bags:
        raise ValueError(f"no reference run of material {material!r}")
    return bags


def run_model(bag: str) -> HsaParams:
    """The model of run ``bag``: its material with its logbook σ_a,eq."""
    cond = load_run(bag).conditions
    return load_params(cond.material).replace(sigma_a_eq=np.asarray(cond.sigma_a_eq, float))


def static_pairs(bag: str) -> StaticPairs:
    """The pairs of run ``bag``: means over the last :data:`WINDOW` seconds of each step."""
    run = load_run(bag)
    model = run_model(bag)
    ends = np.append(run.step_instants, run.t[-1] + 0.01)
    phi, p, p_des, spread, theta = [], [], [], [], []
    for end in ends:
        w = (run.phi.t >= end - WINDOW) & (run.phi.t < end)
        both = np.stack([run.phi["phi1"][w], run.phi["phi2"][w]], axis=1)
        phi.append(both.mean(axis=0))
        spread.append(np.ptp(both, axis=0))
        g = (run.t >= end - WINDOW) & (run.t < end)
        p.append(run.p[g].mean(axis=0))
        p_des.append(run.p_des[g].mean(axis=0))
        k = (run.q.t >= end - WINDOW) & (run.q.t < end)
        q = [run.q[n][k].mean() for n in ("kappa_be", "sigma_sh", "sigma_ax")]
        theta.append(float(kinematics.end_effector_pose(model, np.array(q))[2]))
    p_des = np.array(p_des)
    move = np.append(np.nan, np.diff(p_des[:, 0]))
    return StaticPairs(np.array(phi), np.array(p), p_des, np.array(theta), move, np.array(spread))


@jax.jit
def _static_poses(plant: HsaParams, phis: jnp.ndarray) -> jnp.ndarray:
    """(n, 3) end-effector poses of ``plant`` at rest at each of ``phis`` (n, 2)."""

    def one(phi: jnp.ndarray) -> jnp.ndarray:
        q, _ = static_equilibrium(plant, phi, jnp.zeros(3))
        return kinematics.end_effector_pose(plant, q)

    return jax.vmap(one)(phis)


class StaticMap:
    """The model's static end-effector poses at the recorded φ of each run, per world."""

    def __init__(self, bags: tuple[str, ...]) -> None:
        """Load the runs' pairs and models (logbook σ_a,eq)."""
        self.pairs = {b: static_pairs(b) for b in bags}
        self.models = {b: run_model(b) for b in bags}

    def residuals(self, bag: str, world: DisturbanceModel) -> np.ndarray:
        """(n, 3) [m] model − robot at the run's pairs in ``world``: x, y and l·θ."""
        model = self.models[bag]
        pairs = self.pairs[bag]
        pose = np.asarray(_static_poses(world.plant_params(model), pairs.phi))
        return np.column_stack([pose[:, :2] - pairs.p, (pose[:, 2] - pairs.theta) * float(model.l)])


def world_of(values: dict[str, float], base: DisturbanceModel | None = None) -> DisturbanceModel:
    """``base`` (default: the default world with stiffness_scale 1) with the fields of
    ``values``."""
    base = DisturbanceModel(stiffness_scale=1.0) if base is None else base
    return dataclasses.replace(base, **{n: float(v) for n, v in values.items()})


def rms(r: np.ndarray) -> float:
    """[m] RMS over pairs of the norm of residuals (n, k)."""
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1))))


def component_rms(r: np.ndarray) -> list[float]:
    """[mm] RMS of each residual component (x, y, l·θ) of residuals (n, 3) [m]."""
    return (np.sqrt(np.mean(r**2, axis=0)) * 1e3).tolist()


def residual_summary(r: np.ndarray) -> dict[str, float | list[float]]:
    """[mm] RMS of residuals (n, 3) [m]: of (x, y, l·θ), of (x, y) and per component."""
    return {
        "rms_mm": rms(r) * 1e3,
        "xy_rms_mm": rms(r[:, :2]) * 1e3,
        "component_rms_mm": component_rms(r),
    }


def fit(
    smap: StaticMap,
    bags: tuple[str, ...],
    names: tuple[str, ...],
    base: DisturbanceModel | None = None,
) -> dict:
    """Least squares of the fields ``names`` (over ``base``, world_of's default) on the pairs of
    ``bags``: ``values``, ``std`` (one standard error), ``at_bound`` (fields ending at a bound of
    :data:`BOUNDS`), ``pooled_rms_mm`` (RMS of the residual's norm over all pairs)."""
    from scipy.optimize import least_squares

    def f(x: np.ndarray) -> np.ndarray:
        w = world_of(dict(zip(names, x)), base)
        return np.concatenate([smap.residuals(b, w).ravel() for b in bags]) * 1e3

    bounds = np.array([BOUNDS[n] for n in names]).T
    sol = least_squares(f, [START[n] for n in names], diff_step=1e-4, bounds=bounds)
    dof = max(len(sol.fun) - len(names), 1)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * float(np.sum(sol.fun**2)) / dof
    at_bound = [n for n, v in zip(names, sol.x) if min(abs(v - b) for b in BOUNDS[n]) < 1e-6]
    return {
        "values": dict(zip(names, sol.x.tolist())),
        "std": dict(zip(names, np.sqrt(np.diag(cov)).tolist())),
        "at_bound": at_bound,
        "pooled_rms_mm": float(np.sqrt(np.mean(sol.fun**2) * 3)),
    }


def fit_field_set(smap: StaticMap, bags: tuple[str, ...], names: tuple[str, ...]) -> dict:
    """:func:`fit` of ``names`` on ``bags`` with each run's residual summary (``per_run``) and,
    for several runs, ``leave_one_run_out``: per run the values fitted on the others and its
    residual summary in that world."""
    res = fit(smap, bags, names)
    w = world_of(res["values"])
    res["per_run"] = {b: residual_summary(smap.residuals(b, w)) for b in bags}
    if len(bags) > 1:
        res["leave_one_run_out"] = {}
        for left in bags:
            sub = fit(smap, tuple(b for b in bags if b != left), names)
            r = smap.residuals(left, world_of(sub["values"]))
            res["leave_one_run_out"][left] = {"values": sub["values"], **residual_summary(r)}
    return res


def approach_direction(smap: StaticMap, bags: tuple[str, ...], world: DisturbanceModel) -> dict:
    """The residual in x of ``world`` against the sign of each step's move in x, per run, and
    pooled the fit residual_x = c + h·sign(move_x) with h's standard error (a static map gives
    h ≈ 0; hysteresis, the robot stopping short, gives h > 0)."""
    direction: dict = {}
    for b in bags:
        r = smap.residuals(b, world)[:, 0] * 1e3
        move = smap.pairs[b].move_x
        up, down = r[move > 0], r[move < 0]
        direction[b] = {
            "residual_x_mm": r.round(3).tolist(),
            "move_x_mm": (move * 1e3).round(1).tolist(),
            "mean_after_plus_x_mm": float(up.mean()),
            "mean_after_minus_x_mm": float(down.mean()),
        }
    all_r = np.concatenate([np.array(d["residual_x_mm"]) for d in direction.values()])
    sign = np.sign(np.nan_to_num(np.concatenate([d["move_x_mm"] for d in direction.values()])))
    keep = sign != 0
    a = np.stack([np.ones(keep.sum()), sign[keep]], axis=1)
    coef, *_ = np.linalg.lstsq(a, all_r[keep], rcond=None)
    left = all_r[keep] - a @ coef
    dof = max(int(keep.sum()) - 2, 1)
    cov = np.linalg.inv(a.T @ a) * float(np.sum(left**2)) / dof
    direction["pooled"] = {
        "fit": "residual_x = c + h sign(move_x), the fitted world",
        "c_mm": float(coef[0]),
        "h_mm": float(coef[1]),
        "h_std_mm": float(np.sqrt(cov[1, 1])),
        "residual_x_rms_mm": float(np.sqrt(np.mean(all_r[keep] ** 2))),
        "after_direction_term_rms_mm": float(np.sqrt(np.mean(left**2))),
    }
    return direction


def static_analysis(
    material: str,
    bags: tuple[str, ...],
    progress: Callable[[str, dict], None] | None = None,
) -> dict:
    """The static fit of ``material`` (a key of :data:`CHOSEN`) on ``bags``: the declared and the
    plant = model worlds' residuals, every field set of :data:`FIELD_SETS`
    (:func:`fit_field_set`; ``progress(label, result)`` after each), the stiffness profile of the
    chosen set and the approach direction in its world."""
    smap = StaticMap(bags)
    out: dict = {"pairs_per_run": {b: len(smap.pairs[b].phi) for b in bags}}
    for label, world in (("declared", DisturbanceModel()), ("plant_equals_model", None)):
        world = DisturbanceModel.none() if world is None else world
        out[f"{label}_world"] = {b: residual_summary(smap.residuals(b, world)) for b in bags}
    sets = {}
    for label, names in FIELD_SETS.items():
        sets[label] = fit_field_set(smap, bags, names)
        if progress is not None:
            progress(label, sets[label])
    out["fits"] = sets
    chosen = sets[CHOSEN[material]]
    names = tuple(n for n in chosen["values"] if n != "stiffness_scale")
    out["stiffness_profile"] = {
        "stiffness_scale": list(STIFFNESS_FACTORS),
        "pooled_rms_mm": [
            fit(smap, bags, names, DisturbanceModel(stiffness_scale=k))["pooled_rms_mm"]
            for k in STIFFNESS_FACTORS
        ],
        "note": "the chosen set refitted at each stiffness factor",
    }
    out["approach_direction"] = approach_direction(smap, bags, world_of(chosen["values"]))
    return out


def field_status(name: str, value: float, std: float) -> FieldStatus:
    """A fitted field of the chosen set: not identified where its default is 0 and it is within
    two standard errors of 0, else identified."""
    if name in ZERO_DEFAULT and abs(value) < 2.0 * std:
        return FieldStatus.WITHIN_NOISE_OF_ZERO
    return FieldStatus.IDENTIFIED


def world_document(material: str, analysis: dict, source: str) -> dict:
    """The static world of ``material`` from its :func:`static_analysis` (``source``: what wrote
    it). Per field: ``value`` (the one in force: the fitted one if identified, else the kept
    one), ``std``, ``fitted`` where not in force, ``leave_one_run_out`` range, ``status``. The
    stiffness factor is kept at 1 (its profile in the status), and a field at a bound in any fit
    and outside the chosen set is kept at its start value."""
    chosen = analysis["fits"][CHOSEN[material]]
    fields = {}
    for name, value in chosen["values"].items():
        std = chosen["std"][name]
        status = field_status(name, value, std)
        entry = {"value": value, "std": std, "status": status.value}
        if status is not FieldStatus.IDENTIFIED:
            entry = {"value": 0.0, "fitted": value, "std": std, "status": status.value}
        if "leave_one_run_out" in chosen:
            loro = [r["values"][name] for r in chosen["leave_one_run_out"].values()]
            entry["leave_one_run_out"] = [min(loro), max(loro)]
        fields[name] = entry
    prof = analysis["stiffness_profile"]
    rms_at = ", ".join(
        f"{k:g}: {v:.2f} mm" for k, v in zip(prof["stiffness_scale"], prof["pooled_rms_mm"])
    )
    fields["stiffness_scale"] = {
        "value": 1.0,
        "status": f"{FieldStatus.PROFILE_FLAT.value} (profile {rms_at}); kept at the identified"
        " parameter set",
    }
    for label, fit_ in analysis["fits"].items():
        for name in fit_["at_bound"]:
            if name not in fields:
                fields[name] = {
                    "value": START[name],
                    "fitted": fit_["values"][name],
                    "status": f"{FieldStatus.AT_BOUND.value} in fit {label!r}",
                }
    return {
        "what": "the world's static plant/model mismatch fitted to the real robot at rest",
        "source": source,
        "adopted": ADOPTED[material][0],
        "status": ADOPTED[material][1],
        "field_set": CHOSEN[material],
        "fields": fields,
    }

"""Closed-loop experiments without ROS: the paper's pipeline in one process, on a simulated plant.

Time runs on a 1 ms grid. On it: the plant (the JAX model with the declared plant/model mismatch of
:mod:`hsa_core.disturbance`) is integrated with the input held; mocap samples the true end-effector pose every 5 ms
(200 Hz) with noise, and each sample reaches the estimator (closed-form IK + causal Savitzky–Golay, exactly the
kinematics node's code path) after the measurement latency; the controller ticks at ``rate`` Hz (40 Hz default,
must divide 1000) on the newest ready state; its command reaches the plant, quantized to motor ticks, after the
actuation latency. Setpoints come from the planner (the planner node's code path) when the reference changes; a
failed plan keeps the previous setpoint and is reported.

The robot first hangs at φ = 0 for ``settle`` seconds while the estimator fills; the reference then starts together
with the first controller output (t = 0 of the metrics, experiments.md §4).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from hsa_core import cli, kinematics, metrics, plotting, simulation
from hsa_core.actuation import MotorMap
from hsa_core.control import CollocatedGains, Controller, ControllerKind, EeIntegralGains, PidGains, default_gains
from hsa_core.disturbance import DisturbanceModel
from hsa_core.estimation import SavitzkyGolayDifferentiator, configuration_from_pose
from hsa_core.params import HsaParams, load_params
from hsa_core.planning import Planner, PlanResult, Setpoint
from hsa_core.runlog import RunLog
from hsa_core.trajectories import TimedReference, circle_reference, contour_reference, star_reference, step_reference

GRID_DT = 1e-3  # s, event grid of the experiment
MOCAP_PERIOD_STEPS = 5  # 200 Hz
PLANT_SUBSTEPS = 2  # RK4 steps of GRID_DT / 2 per grid interval


@dataclass(frozen=True)
class ExperimentConfig:
    """What to run: material, law, options, reference, rate, disturbance and the hang-still time before start."""

    material: str = "fpu"
    controller: str = "psatid"
    ee_integral: bool = False
    reference: TimedReference | None = None  # default: the material's 11-step list
    rate: float = 40.0
    disturbance: DisturbanceModel = field(default_factory=DisturbanceModel)
    settle: float = 0.5
    planner: str | None = None  # default planner of the material
    gains: CollocatedGains | PidGains | None = None  # default: the paper's gains for the law and material

    @property
    def name(self) -> str:
        """Run label used in tables and file names."""
        return f"{self.material}_{self.controller}{'_eei' if self.ee_integral else ''}"


@dataclass
class ExperimentResult:
    """The per-tick log, the metrics, noise-free plant truth at the ticks and planner failures."""

    config: ExperimentConfig
    log: RunLog
    metrics: metrics.RunMetrics
    true_chiee: np.ndarray  # plant EE pose at each tick (no noise, no latency)
    plan_failures: list[tuple[float, PlanResult]]
    wall_time: float

    def true_steady_state_error(self) -> float:
        """Mean over steps after the first of ‖p^d − p_true‖ in each step's last 2 s [m] (noise-free e_ss)."""
        errors = []
        for step in self.metrics.steps[1:]:
            window = (self.log.t >= step.t_end - metrics.STEADY_STATE_WINDOW) & (self.log.t < step.t_end)
            e = np.linalg.norm(self.log.chiee_des[window, :2] - self.true_chiee[window, :2], axis=1)
            errors.append(float(np.mean(e)))
        return float(np.mean(errors)) if errors else math.nan


def _advance_fn(plant: HsaParams):
    """Jitted plant advance over one grid interval with the input held (zero-order hold)."""
    dt = GRID_DT / PLANT_SUBSTEPS

    @jax.jit
    def advance(x: jax.Array, phi: jax.Array) -> jax.Array:
        return simulation.simulate(plant, x, phi[None, :], dt, PLANT_SUBSTEPS)[-1]

    return advance


def run_experiment(config: ExperimentConfig, progress: bool = False) -> ExperimentResult:
    """Run one closed-loop experiment (see the module docstring) and evaluate it."""
    wall0 = time.perf_counter()
    model = load_params(config.material)
    dist = config.disturbance
    plant = dist.plant_params(model)
    reference = config.reference or step_reference(config.material)
    ticks_per_control = 1000.0 / config.rate
    if abs(ticks_per_control - round(ticks_per_control)) > 1e-9 or ticks_per_control < 1:
        raise ValueError(f"rate must divide 1000 Hz (the experiment's 1 ms grid), got {config.rate}")
    control_every = int(round(ticks_per_control))

    planner = Planner(model, config.planner)
    controller = Controller(
        ControllerKind(config.controller), model, config.gains, dt=1.0 / config.rate,
        ee_integral=EeIntegralGains() if config.ee_integral else None,
    )
    motor_map = MotorMap(phi_max=float(np.max(np.asarray(model.phi_max))))
    advance = _advance_fn(plant)
    ee_pose = jax.jit(kinematics.end_effector_pose)
    rng = dist.rng()
    estimator = SavitzkyGolayDifferentiator(window=20, order=3, dim=6, nominal_period=MOCAP_PERIOD_STEPS * GRID_DT)

    # start hanging at rest with phi = 0: the plant's static equilibrium
    x = np.array(simulation.steady_state_rollout(plant, np.zeros(2)))
    x[3:] = 0.0
    phi_goal = np.zeros(2)  # twist the motors are commanded to (after latency and quantization)
    phi_applied = np.zeros(2)  # twist the motors have reached
    settle_steps = int(round(config.settle / GRID_DT))
    total_steps = settle_steps + int(math.ceil(reference.duration / GRID_DT))
    measurements: list[tuple[float, float, np.ndarray]] = []  # (available at, stamp, noisy chiee)
    commands: list[tuple[float, np.ndarray]] = []  # (applied at, realised phi)
    state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    t0: float | None = None
    setpoint: Setpoint | None = None
    ref_index = -1
    failures: list[tuple[float, PlanResult]] = []
    rows: list[tuple] = []
    truth: list[np.ndarray] = []

    bar = _progress(total_steps, config.name) if progress else None
    for n in range(total_steps):
        t = n * GRID_DT
        true_pose = np.asarray(ee_pose(plant, x[:3]))
        if n % MOCAP_PERIOD_STEPS == 0:
            measurements.append((t + dist.measurement_latency, t, dist.measure(rng, true_pose)))
        while measurements and measurements[0][0] <= t + 1e-12:
            _, stamp, chiee = measurements.pop(0)
            q = configuration_from_pose(model, chiee)
            est = estimator.update(stamp, np.concatenate([q, chiee]))
            if est.ready:
                state = (q, est.derivative[:3], chiee, est.derivative[3:])
        if n >= settle_steps and n % control_every == 0 and state is not None:
            if t0 is None:
                t0 = t
            idx = reference.index(t - t0)
            if idx != ref_index:
                ref_index = idx
                result = planner.plan(reference.p_des[idx], warm_start=len(reference) > 20)
                if result.success:
                    setpoint = result.setpoint
                else:
                    failures.append((t - t0, result))
            if setpoint is not None:
                phi_cmd, info = controller.step(*state, setpoint=setpoint)
                commands.append((t + dist.actuation_latency, dist.realised_twist(motor_map, phi_cmd)))
                rows.append((t - t0, info))
                truth.append(true_pose)
        while commands and commands[0][0] <= t + 1e-12:
            phi_goal = commands.pop(0)[1]
        phi_applied = dist.servo_step(phi_applied, phi_goal, GRID_DT)
        x = np.asarray(advance(x, phi_applied))
        if bar is not None and n % 1000 == 0:
            bar.update(min(1000, total_steps - n))
    if bar is not None:
        bar.close()
    if not rows:
        raise RuntimeError(f"{config.name}: the controller never ran (no setpoint could be planned)")

    log = _to_runlog(rows, config, model)
    run_metrics = metrics.evaluate_run(
        log.t, log.chiee_des[:, :2], log.chiee[:, :2], log.saturated, duration=reference.duration, name=config.name
    )
    return ExperimentResult(config, log, run_metrics, np.asarray(truth), failures, time.perf_counter() - wall0)


def _to_runlog(rows: list[tuple], config: ExperimentConfig, model: HsaParams) -> RunLog:
    """Stack the controller-info records of all ticks into a RunLog."""
    t = np.array([r[0] for r in rows])
    infos = [r[1] for r in rows]

    def stack(name: str) -> np.ndarray:
        return np.array([np.asarray(getattr(i, name), dtype=np.float64) for i in infos])

    return RunLog(
        t=t, chiee=stack("chiee"), chiee_des=stack("chiee_des"), q=stack("q"), q_des=stack("q_des"),
        varphi=stack("varphi"), varphi_des=stack("varphi_des"), phi_ss=stack("phi_ss"),
        phi_unsat=stack("phi_des_unsat"), phi_sat=stack("phi_des_sat"), e_int=stack("e_int"),
        saturated=np.array([bool(i.saturated) for i in infos]),
        meta={"material": config.material, "controller": config.controller + (" + EE integral" if config.ee_integral else ""),
              "rate_hz": str(config.rate), "phi_max": str(float(np.max(np.asarray(model.phi_max))))},
    )


def _progress(total: int, label: str):
    """A tqdm bar over grid steps (stderr), advanced in 1 s chunks of simulated time."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="ms sim", unit_scale=True, file=sys.stderr, leave=False)


def _reference(args: argparse.Namespace) -> TimedReference | None:
    """Build the reference selected on the command line (None = the material's step list)."""
    if args.trajectory == "steps":
        return None
    if args.trajectory == "star":
        return star_reference()
    if args.trajectory == "circle":
        return circle_reference()
    return contour_reference(args.trajectory, k=args.contour_k)


LAWS = ("psatid", "psatid_gc", "pid", "psatid+eei", "psatid_gc+eei")
"""Laws the CLI runs (``+eei``: with the EE-position integral extension); ``all`` = every one but psatid_gc+eei."""


def _laws(text: str) -> list[str]:
    """argparse type of --controller: 'all' or a comma-separated list of LAWS, checked before anything runs."""
    if text == "all":
        return ["psatid", "psatid_gc", "pid", "psatid+eei"]
    laws = text.split(",")
    bad = [law for law in laws if law not in LAWS]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown law(s) {bad}; choose from {list(LAWS)} or 'all'")
    return laws


def _rate(text: str) -> float:
    """argparse type of --rate: a control rate [Hz] whose period is a whole number of the 1 ms grid steps."""
    rate = float(text)
    ticks = 1000.0 / rate if rate > 0 and math.isfinite(rate) else 0.0
    if ticks < 1 or abs(ticks - round(ticks)) > 1e-9:
        raise argparse.ArgumentTypeError(f"must divide 1000 Hz (the 1 ms simulation grid), e.g. 40, 100, 200; "
                                         f"got {text}")
    return rate


def _trajectory(text: str) -> str:
    """argparse type of --trajectory: steps, star, circle or an existing image file."""
    if text in ("steps", "star", "circle") or Path(text).is_file():
        return text
    raise argparse.ArgumentTypeError(f"must be steps, star, circle or an image file; {text!r} is none of them")


def main(argv: list[str] | None = None) -> int:
    """CLI: run the selected experiments, print the metrics table, write figures, logs (NPZ, CSV) and a summary."""
    parser = cli.ArgumentParser(prog="hsa_experiment",
                                description="Closed-loop HSA experiments in simulation, without ROS.")
    parser.add_argument("--material", choices=["fpu", "epu", "both"], default="fpu")
    parser.add_argument("--controller", type=_laws, default="all",
                        help="psatid, psatid_gc, pid, psatid+eei, psatid_gc+eei, or 'all' (comma-separated list ok)")
    parser.add_argument("--trajectory", type=_trajectory, default="steps",
                        help="steps, star, circle, or the path of an image file")
    parser.add_argument("--contour-k", type=cli.positive_int, default=5,
                        help="keep every k-th contour point (image references)")
    parser.add_argument("--rate", type=_rate, default=40.0, help="control rate [Hz], must divide 1000")
    parser.add_argument("--duration", type=cli.positive, default=None,
                        help="truncate the reference to this many seconds")
    parser.add_argument("--kd", type=cli.positive, default=None,
                        help="override K_d of the collocated laws (the paper used 0.02, and 0.01 from 2023-10-19)")
    parser.add_argument("--disturbance", choices=["default", "none", "shear"], default="default",
                        help="declared disturbance model (hsa_core.disturbance); 'shear' adds a shear-stiffness mismatch")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/experiments"))
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    materials = ["fpu", "epu"] if args.material == "both" else [args.material]
    laws = args.controller
    dist = {"default": DisturbanceModel(seed=args.seed), "none": DisturbanceModel.none(),
            "shear": DisturbanceModel.shear_mismatch(args.seed)}[args.disturbance]
    results = []
    for material in materials:
        for law in laws:
            kind, _, ext = law.partition("+")
            reference = _reference(args) or step_reference(material)
            if args.duration is not None:
                keep = reference.t < args.duration
                reference = TimedReference(reference.t[keep], reference.p_des[keep], reference.name,
                                           min(args.duration, reference.duration))
            gains = None
            if args.kd is not None and kind != "pid":
                gains = dataclasses.replace(default_gains(kind, material), kd=args.kd)
            config = ExperimentConfig(material, kind, ext == "eei", reference, args.rate, dist, gains=gains)
            result = run_experiment(config, progress=not args.quiet)
            results.append(result)
            out = args.out / config.name
            out.mkdir(parents=True, exist_ok=True)
            result.log.save_npz(out / "log.npz")
            result.log.save_csv(out / "log.csv")
            if not args.no_figures:
                plotting.all_figures(result.log, out, phi_max=float(result.log.meta["phi_max"]),
                                     contour=args.trajectory != "steps")
            for t_fail, failure in result.plan_failures:
                print(f"[{config.name}] planning failed at t = {t_fail:.2f} s: {failure.status.name}: {failure.message}")
    print(metrics.format_summary([r.metrics for r in results]))
    print("\nnoise-free steady-state error (plant truth, mean over steps after the first):")
    for r in results:
        print(f"  {r.config.name:<24} {r.true_steady_state_error() * 1e3:6.3f} mm   (wall time {r.wall_time:5.1f} s)")
    print(f"\nlogs and figures in {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

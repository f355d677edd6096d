"""Closed-loop experiments without ROS: the paper's pipeline in one process, on the world of
:mod:`hsa_core.sim.world`.

The timeline is the one the ROS graph runs in lockstep (docs/simulation.md), so that for the same
configuration and seed both produce the same ticks to float round-off:

* the world (plant, servos, mocap) runs on its 1 ms grid from t = 0, the robot hanging at rest with
  φ = 0;
* at every instant, first the timers due at that instant run (sequencer, controller), then the mocap
  samples that became available are handed to the estimator (closed-form IK + causal Savitzky–Golay:
  the kinematics node's code path) — in the graph, an instant's samples go out once the instant is
  finished;
* the setpoint sequencer plans point k at S_k = S_0 + t_k (t_k: the reference's point times); S_0 is
  its first supervision tick after the start delay (:func:`first_point_ns`, the sequencer's rule); a
  failed plan keeps the previous setpoint and is reported;
* the controller ticks every 1/``rate`` s from t = 0 through controller_node's own tick
  (hsa_core.controller.control_loop: the same Supervisor, with the node's default bounds and no
  driver watch, :data:`CONTROLLER_SUPERVISION`): a tick activates the setpoints planned strictly
  before it and sends nothing before it has a setpoint and a state; it steps the law on the newest
  state while that is at most ``stale_timeout`` old, re-sends the last command (the law not stepped)
  while it is at most ``hold_timeout`` old, and sends nothing after that. In a fault-free run every
  tick with a setpoint and a state tracks; ``mocap_outages`` withholds samples to show the rest;
* its command goes to the motors as the driver writes it (clipped to [0, φ_max], goal ticks
  truncated towards zero) and takes effect after the world's actuation latency; a re-sent command is
  written again, and with nothing sent the motors keep the goals of the last write (the driver's
  watchdog hold).

A run profile (hsa_core.runs.profiles) sets the conditions of a period: :func:`profile_config`
applies one (rate, integrator step, velocity estimator, σ_a,eq, payload), :func:`replay_config` a
paper run's own (hsa_core.runs.catalogue: its profile, law, gains, σ_a,eq, payload and setpoints;
the real step instants of a packaged reference run). With the ``smoothing_spline_16`` estimator the
kinematics node's estimator is replaced by the September stand-in: at every tick the newest mocap
state enters a 16-sample cubic end-point fit on the true stamps, and the state it gives goes to the
tick. A payload is the plant's (it hangs at rest with it from t = 0, at the paper's payload CoG);
the controller's model keeps the material's.

t = 0 of the metrics is the first tick that sends a command (experiments.md §4); the run ends
``reference.duration`` later. The log holds the tracking ticks (as hsa_bag.analysis reads a bag);
``ExperimentResult.ticks`` every tick.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hsa_core import cli
from hsa_core.analysis import metrics, plotting
from hsa_core.controller.control import (
    CollocatedGains,
    Controller,
    ControllerKind,
    EeIntegralGains,
    PidGains,
    default_gains,
)
from hsa_core.controller.control_loop import ControlLoop
from hsa_core.controller.supervision import (
    HOLD_TIMEOUT,
    STALE_TIMEOUT,
    Action,
    Mode,
    Supervisor,
    SupervisorConfig,
)
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.params import HsaParams, load_params
from hsa_core.model.wiring import load_wiring
from hsa_core.runs.catalogue import Replayable
from hsa_core.runs.profiles import (
    DEFAULT_PROFILE,
    RunProfile,
    VelocityEstimator,
    load_profile,
)
from hsa_core.runs.runlog import RunLog
from hsa_core.sensing.estimation import SavitzkyGolayDifferentiator, configuration_from_pose
from hsa_core.sim.disturbance import (
    DEFAULT_WORLD,
    WORLDS,
    DisturbanceModel,
    default_world,
    named_world,
)
from hsa_core.sim.run_conditions import (
    TickEstimator,
    plant_params,
    rest_strain_shift,
    run_disturbance,
)
from hsa_core.sim.world import GRID_NS, MOCAP_PERIOD_NS, World, seconds_to_ns
from hsa_core.task.planning import Planner, PlanResult
from hsa_core.task.sequencer_timing import first_point_ns
from hsa_core.task.trajectories import (
    TimedReference,
    circle_reference,
    contour_reference,
    star_reference,
    step_reference,
)

ESTIMATOR_WINDOW, ESTIMATOR_ORDER, GAP_FACTOR = 20, 3, 5.0
"""The kinematics node's estimator settings (hsa_kinematics_node/config/<material>.yaml)."""
CONTROLLER_SUPERVISION = SupervisorConfig(STALE_TIMEOUT, HOLD_TIMEOUT, driver_timeout=0.0)
"""controller_node's default bounds; no driver watch: offline the driver is modelled inline and
cannot be lost."""


@dataclass(frozen=True)
class ExperimentConfig:
    """What to run: material, law, options, reference, rate, disturbance, the sequencer's start
    delay and the run's conditions (profile name, velocity estimator, integrator step, σ_a,eq,
    payload; :func:`profile_config`)."""

    material: str = "fpu"
    controller: str = "psatid"
    ee_integral: bool = False
    reference: TimedReference | None = None  # default: the material's 11-step list
    rate: float = 40.0
    disturbance: DisturbanceModel | None = None  # None: the material's default_world
    start_delay: float = 0.0
    planner: str | None = None  # default planner of the material
    # default: the paper's gains for the law and material
    gains: CollocatedGains | PidGains | None = None
    mocap_outages: tuple[
        tuple[float, float], ...
    ] = ()  # [s] world-time windows [start, end): samples stamped in
    # them never reach the estimator (a fault for the supervision; hsa_core.sim.closed_loop models
    # fault-free runs only)
    # σ_a,eq per rod calibrated before the run (default: the
    sigma_a_eq: tuple[float, float] | None = None
    # material's nominal): the controller's model's, and the plant's plus the disturbance's
    # rest_strain_offset
    profile: str = DEFAULT_PROFILE  # the run profile these conditions come from (a label)
    velocity_estimator: VelocityEstimator = VelocityEstimator.SAVITZKY_GOLAY_20
    # [s] the integrators' step (None: the control period 1/rate)
    integrator_dt: float | None = None
    # [kg] the plant's point payload m_pl (the controller's model keeps the material's)
    payload: float = 0.0
    command_latency: float = 0.0  # [s] tick → goal on the bus (controller side; run_disturbance)
    # the goals' path to the bus: the September queue's depth (0: none) and transaction [s]
    # (hsa_core.sim.command_queue; run_disturbance)
    command_queue: tuple[int, float] = (0, 0.0)
    # σ_a,eq per rod of the plant where it differs from the controller's model (default: the
    # model's); the disturbance's rest_strain_offset still adds to it
    plant_sigma_a_eq: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        """Reject a negative payload, a non-positive integrator step and a σ_a,eq that is not two
        values > 0."""
        if not (math.isfinite(self.payload) and self.payload >= 0.0):
            raise ValueError(f"payload must be a finite mass >= 0 kg, got {self.payload}")
        if self.integrator_dt is not None and not (
            math.isfinite(self.integrator_dt) and self.integrator_dt > 0.0
        ):
            raise ValueError(f"integrator_dt must be > 0 s, got {self.integrator_dt}")
        if not (math.isfinite(self.command_latency) and self.command_latency >= 0.0):
            raise ValueError(f"command_latency must be >= 0 s, got {self.command_latency}")
        if self.sigma_a_eq is not None and (
            len(self.sigma_a_eq) != 2
            or not all(math.isfinite(v) and v > 0.0 for v in self.sigma_a_eq)
        ):
            raise ValueError(f"sigma_a_eq must be two values > 0, got {self.sigma_a_eq}")
        if self.plant_sigma_a_eq is not None and (
            len(self.plant_sigma_a_eq) != 2
            or not all(math.isfinite(v) and v > 0.0 for v in self.plant_sigma_a_eq)
        ):
            raise ValueError(
                f"plant_sigma_a_eq must be two values > 0, got {self.plant_sigma_a_eq}"
            )

    def model(self) -> HsaParams:
        """The controller's model: the material's parameter set with the run's σ_a,eq."""
        params = load_params(self.material)
        return (
            params
            if self.sigma_a_eq is None
            else params.replace(sigma_a_eq=np.asarray(self.sigma_a_eq, float))
        )

    @property
    def rest_strain_shift(self) -> tuple[float, float]:
        """The plant's σ_a,eq minus the controller's model's, per rod (0 without
        ``plant_sigma_a_eq``)."""
        if self.plant_sigma_a_eq is None:
            return (0.0, 0.0)
        return rest_strain_shift(self.model(), self.plant_sigma_a_eq)

    def base_world(self) -> DisturbanceModel:
        """The world this run names: ``disturbance``, or the material's
        :func:`~hsa_core.sim.disturbance.default_world`."""
        return default_world(self.material) if self.disturbance is None else self.disturbance

    def in_world(self, **fields: Any) -> ExperimentConfig:
        """This run in its base world with ``fields`` replaced (e.g. a mocap noise ``seed``)."""
        return dataclasses.replace(
            self, disturbance=dataclasses.replace(self.base_world(), **fields)
        )

    def world(self) -> DisturbanceModel:
        """The world of this run: :meth:`base_world` with the run's command latency and queue and
        its plant σ_a,eq (:func:`hsa_core.sim.run_conditions.run_disturbance`)."""
        return run_disturbance(
            self.base_world(), self.command_latency, self.rest_strain_shift, self.command_queue
        )

    @property
    def name(self) -> str:
        """Run label used in tables and file names."""
        return f"{self.material}_{self.controller}{'_eei' if self.ee_integral else ''}"


def profile_config(
    profile: RunProfile,
    material: str = "fpu",
    controller: str = "psatid",
    *,
    sigma_a_eq: tuple[float, float] | None = None,
    payload: float | None = None,
    **options: object,
) -> ExperimentConfig:
    """The experiment of ``material`` and ``controller`` under ``profile``: its rate, integrator
    step, estimator, command latency and queue, σ_a,eq and payload (``sigma_a_eq`` / ``payload``
    override the profile's); ``options``: other ExperimentConfig fields (reference, gains,
    disturbance, ...)."""
    return ExperimentConfig(
        material,
        controller,
        rate=profile.rate,
        profile=profile.name,
        velocity_estimator=profile.velocity_estimator,
        integrator_dt=profile.integrator_dt,
        command_latency=profile.command_latency_ms * 1e-3,
        command_queue=(profile.command_queue_depth, profile.command_transaction_ms * 1e-3),
        sigma_a_eq=sigma_a_eq if sigma_a_eq is not None else profile.sigma_a_eq,
        payload=payload if payload is not None else profile.payload,
        **options,
    )


def replay_config(
    run: Replayable,
    *,
    sigma_a_eq: tuple[float, float] | None = None,
    payload: float | None = None,
    **options: object,
) -> ExperimentConfig:
    """A paper run (:func:`hsa_core.runs.catalogue.replayable`) replayed with its own conditions:
    its profile, material, law, gains, σ_a,eq and payload, and its setpoints at their instants (the
    real step instants of a packaged run; ``sigma_a_eq`` / ``payload`` override the run's). A PID
    run (its law needs no plan) whose σ_a,eq leaves a setpoint without a plan keeps that σ_a,eq in
    the plant (``plant_sigma_a_eq``) and gives the controller's model the material's nominal one,
    so the sequencer passes every setpoint as the original did."""
    cond = run.conditions
    config = profile_config(
        cond.profile,
        cond.material,
        cond.law.value,
        gains=cond.gains,
        sigma_a_eq=sigma_a_eq if sigma_a_eq is not None else cond.sigma_a_eq,
        payload=payload if payload is not None else cond.payload,
        reference=run.timed_reference(),
        **options,
    )
    if cond.law is not ControllerKind.PID or config.sigma_a_eq is None:
        return config
    planner = Planner(config.model(), config.planner)
    if all(planner.plan(p).success for p in config.reference.p_des):
        return config
    nominal = tuple(float(v) for v in load_params(cond.material).sigma_a_eq)
    return dataclasses.replace(config, sigma_a_eq=nominal, plant_sigma_a_eq=config.sigma_a_eq)


@dataclass(frozen=True)
class TickRecord:
    """One controller tick: world time [ns], mode, what it sent, φ sent [rad] (NaN: nothing) and
    e_int after it."""

    t_ns: int
    mode: Mode
    sent: Action
    phi: np.ndarray
    e_int: np.ndarray


@dataclass
class ExperimentResult:
    """The per-tick log, the metrics, noise-free plant truth at the ticks and planner failures."""

    config: ExperimentConfig
    log: RunLog
    metrics: metrics.RunMetrics
    true_chiee: np.ndarray  # plant EE pose at each tick (no noise, no latency)
    plan_failures: list[tuple[float, PlanResult]]
    wall_time: float
    ticks: list[TickRecord] = field(default_factory=list)  # every controller tick, tracking or not

    def true_steady_state_error(self) -> float:
        """Mean over steps after the first of ‖p^d − p_true‖ in each step's last 2 s [m] (noise-free
        e_ss)."""
        errors = []
        for step in self.metrics.steps[1:]:
            window = (self.log.t >= step.t_end - metrics.STEADY_STATE_WINDOW) & (
                self.log.t < step.t_end
            )
            e = np.linalg.norm(self.log.chiee_des[window, :2] - self.true_chiee[window, :2], axis=1)
            errors.append(float(np.mean(e)))
        return float(np.mean(errors)) if errors else math.nan


def run_experiment(config: ExperimentConfig, progress: bool = False) -> ExperimentResult:
    """Run one closed-loop experiment (see the module docstring) and evaluate it."""
    wall0 = time.perf_counter()
    model = config.model()
    reference = config.reference or step_reference(config.material)
    period_ns = seconds_to_ns(1.0 / config.rate)
    if period_ns % GRID_NS or period_ns < GRID_NS:
        raise ValueError(f"rate must divide 1000 Hz (the world's 1 ms grid), got {config.rate}")
    # the robot's wiring at its nominal neutral, as sim_node's servos
    motor_map = load_wiring().motor_map(model)
    phi_max = motor_map.phi_max
    world = World(
        plant_params(model, config.payload),
        config.world(),
        motor_map,
    )
    planner = Planner(model, config.planner)
    controller = Controller(
        ControllerKind(config.controller),
        model,
        config.gains,
        dt=1.0 / config.rate if config.integrator_dt is None else config.integrator_dt,
        ee_integral=EeIntegralGains() if config.ee_integral else None,
    )
    loop = ControlLoop(controller, Supervisor(CONTROLLER_SUPERVISION))
    # the estimator runs at the ticks
    at_ticks = config.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    tick_estimator = TickEstimator(period_ns * 1e-9)
    estimator = SavitzkyGolayDifferentiator(
        window=ESTIMATOR_WINDOW,
        order=ESTIMATOR_ORDER,
        dim=6,
        gap_factor=GAP_FACTOR,
        nominal_period=MOCAP_PERIOD_NS * 1e-9,
    )
    # the newest sample (stamp, q, χ_ee), for at_ticks
    newest: tuple[int, np.ndarray, np.ndarray] | None = None
    s0 = first_point_ns(config.start_delay)
    points = [s0 + seconds_to_ns(float(t)) for t in reference.t]
    outages = [(seconds_to_ns(a), seconds_to_ns(b)) for a, b in config.mocap_outages]
    warm = len(reference) > 20
    failures: list[tuple[int, PlanResult]] = []
    ticks: list[TickRecord] = []
    origin: int | None = None
    t0: int | None = None
    end: int | None = None
    rows: list[tuple] = []
    truth: list[np.ndarray] = []
    measured: list[
        np.ndarray
    ] = []  # twists the servos report at each tick (what the driver's read gives)
    k = 0
    tick = period_ns
    bar = _progress(reference.duration, config.name) if progress else None
    # a run that has not tracked by the last setpoint plus the duration never will
    give_up = points[-1] + seconds_to_ns(reference.duration)
    while (tick < end) if end is not None else (tick <= give_up):
        instant = min(tick, world.next_sample_ns(), points[k] if k < len(points) else tick)
        world.advance_to(instant)
        if k < len(points) and points[k] == instant:
            result = planner.plan(reference.p_des[k], warm_start=warm)
            if result.success:
                loop.receive_setpoint(instant, result.setpoint)
            else:
                failures.append((instant, result))
            k += 1
        if tick == instant:
            if not np.all(np.isfinite(np.asarray(world.x))):
                raise RuntimeError(
                    f"{config.name}: the simulated plant diverged by t = {instant * 1e-9:.3f} s "
                    "(a world beyond the plant's integration limit, e.g. its damping_scale)"
                )
            if (
                at_ticks
                and newest is not None
                and (rates := tick_estimator.update(*newest)) is not None
            ):
                loop.state(newest[0], instant, newest[1], rates[0], newest[2], rates[1])
            out = loop.tick(instant)
            if (
                out.sent is not Action.NONE
            ):  # a new or a re-sent command, written as the driver writes it
                world.write_goals(
                    motor_map.goal_ticks(np.clip(out.command.phi, 0.0, phi_max)), instant
                )
            if out.sent is Action.STEP:
                if t0 is None:
                    t0, end = instant, instant + seconds_to_ns(reference.duration)
                rows.append(((instant - t0) * 1e-9, out.info))
                truth.append(world.true_pose())
                measured.append(motor_map.present_twists(world.present_ticks()))
                if bar is not None and len(rows) % round(config.rate) == 0:
                    bar.update(1.0)
            phi_sent = out.command.phi if out.sent is not Action.NONE else np.full(2, math.nan)
            ticks.append(TickRecord(instant, out.mode, out.sent, phi_sent, controller.state.e_int))
            tick += period_ns
        for sample in world.take_samples(instant):
            if any(a <= sample.stamp_ns < b for a, b in outages):
                continue
            origin = sample.stamp_ns if origin is None else origin
            q = configuration_from_pose(model, sample.chiee)
            if at_ticks:
                newest = (sample.stamp_ns, q, sample.chiee)
                continue
            est = estimator.update(
                (sample.stamp_ns - origin) * 1e-9, np.concatenate([q, sample.chiee])
            )
            if est.ready:
                loop.state(
                    sample.stamp_ns,
                    instant,
                    q,
                    est.derivative[:3],
                    sample.chiee,
                    est.derivative[3:],
                )
    if bar is not None:
        bar.close()
    if not rows:
        raise RuntimeError(
            f"{config.name}: the controller never ran (no setpoint could be planned, or no "
            "state reached it)"
        )

    log = _to_runlog(rows, config, model, np.asarray(measured))
    run_metrics = metrics.evaluate_run(
        log.t,
        log.chiee_des[:, :2],
        log.chiee[:, :2],
        log.saturated,
        duration=reference.duration,
        name=config.name,
    )
    fails = [((t - (t0 or s0)) * 1e-9, r) for t, r in failures]
    return ExperimentResult(
        config, log, run_metrics, np.asarray(truth), fails, time.perf_counter() - wall0, ticks
    )


def _to_runlog(
    rows: list[tuple], config: ExperimentConfig, model: HsaParams, phi_meas: np.ndarray
) -> RunLog:
    """Stack the controller-info records of all ticks into a RunLog (with the servos' twist at each
    tick)."""
    t = np.array([r[0] for r in rows])
    infos = [r[1] for r in rows]

    def stack(name: str) -> np.ndarray:
        return np.array([np.asarray(getattr(i, name), dtype=np.float64) for i in infos])

    return RunLog(
        t=t,
        chiee=stack("chiee"),
        chiee_des=stack("chiee_des"),
        q=stack("q"),
        q_des=stack("q_des"),
        varphi=stack("varphi"),
        varphi_des=stack("varphi_des"),
        phi_ss=stack("phi_ss"),
        phi_unsat=stack("phi_des_unsat"),
        phi_sat=stack("phi_des_sat"),
        e_int=stack("e_int"),
        saturated=np.array([bool(i.saturated) for i in infos]),
        phi_meas=phi_meas,
        meta={
            "material": config.material,
            "controller": config.controller + (" + EE integral" if config.ee_integral else ""),
            "rate_hz": str(config.rate),
            "phi_max": str(float(np.max(np.asarray(model.phi_max)))),
        },
    )


def _progress(total: float, label: str):
    """A tqdm bar over the run's simulated seconds (stderr)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="s sim", file=sys.stderr, leave=False)


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
"""Laws the CLI runs (``+eei``: with the EE-position integral extension); ``all`` = every one but
psatid_gc+eei."""


def _laws(text: str) -> list[str]:
    """argparse type of --controller: 'all' or a comma-separated list of LAWS, checked before
    anything runs."""
    if text == "all":
        return ["psatid", "psatid_gc", "pid", "psatid+eei"]
    laws = text.split(",")
    bad = [law for law in laws if law not in LAWS]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown law(s) {bad}; choose from {list(LAWS)} or 'all'")
    return laws


def _rate(text: str) -> float:
    """argparse type of --rate: a control rate [Hz] whose period is a whole number of the 1 ms grid
    steps."""
    rate = float(text)
    ticks = 1000.0 / rate if rate > 0 and math.isfinite(rate) else 0.0
    if ticks < 1 or abs(ticks - round(ticks)) > 1e-9:
        raise argparse.ArgumentTypeError(
            f"must divide 1000 Hz (the 1 ms simulation grid), e.g. 40, 100, 200; got {text}"
        )
    return rate


def _trajectory(text: str) -> str:
    """argparse type of --trajectory: steps, star, circle or an existing image file."""
    if text in ("steps", "star", "circle") or Path(text).is_file():
        return text
    raise argparse.ArgumentTypeError(
        f"must be steps, star, circle or an image file; {text!r} is none of them"
    )


def _configs(args: argparse.Namespace) -> list[ExperimentConfig]:
    """The experiments the command line selects: one replayed run, or every material × law under the
    profile, each in the world ``--disturbance`` names for its material."""
    if args.run is not None:
        config = replay_config(args.run, sigma_a_eq=args.sigma_a_eq, payload=args.payload)
        configs = [
            dataclasses.replace(
                config, disturbance=named_world(args.disturbance, config.material, args.seed)
            )
        ]
    else:
        profile = args.profile or load_profile(DEFAULT_PROFILE)
        material = args.material or "fpu"
        configs = []
        for material in ["fpu", "epu"] if material == "both" else [material]:
            for law in args.controller or _laws("all"):
                kind, _, ext = law.partition("+")
                configs.append(
                    profile_config(
                        profile,
                        material,
                        kind,
                        sigma_a_eq=args.sigma_a_eq,
                        payload=args.payload,
                        ee_integral=ext == "eei",
                        reference=_reference(args) or step_reference(material),
                        disturbance=named_world(args.disturbance, material, args.seed),
                    )
                )
    adjusted = []
    for config in configs:
        reference = config.reference
        if args.duration is not None and reference is not None:
            keep = reference.t < args.duration
            reference = TimedReference(
                reference.t[keep],
                reference.p_des[keep],
                reference.name,
                min(args.duration, reference.duration),
            )
        gains = config.gains
        if args.kd is not None and config.controller != "pid":
            gains = dataclasses.replace(
                gains or default_gains(config.controller, config.material), kd=args.kd
            )
        adjusted.append(
            dataclasses.replace(
                config,
                reference=reference,
                gains=gains,
                rate=config.rate if args.rate is None else args.rate,
            )
        )
    return adjusted


def main(argv: list[str] | None = None) -> int:
    """CLI: run the selected experiments, print the metrics table, write figures, logs (NPZ, CSV)
    and a summary."""
    configure_jax()
    parser = cli.ArgumentParser(
        prog="hsa_experiment", description="Closed-loop HSA experiments in simulation, without ROS."
    )
    parser.add_argument(
        "--material", choices=["fpu", "epu", "both"], default=None, help="default: fpu"
    )
    parser.add_argument(
        "--controller",
        type=_laws,
        default=None,
        help=(
            "psatid, psatid_gc, pid, psatid+eei, psatid_gc+eei, or 'all' (comma-separated list ok; "
            "default: all)"
        ),
    )
    cli.add_run_conditions(parser)
    parser.add_argument(
        "--trajectory",
        type=_trajectory,
        default="steps",
        help="steps, star, circle, or the path of an image file",
    )
    parser.add_argument(
        "--contour-k",
        type=cli.positive_int,
        default=5,
        help="keep every k-th contour point (image references)",
    )
    parser.add_argument(
        "--rate",
        type=_rate,
        default=None,
        help="control rate [Hz], must divide 1000 (default: the run's or the profile's)",
    )
    parser.add_argument(
        "--duration",
        type=cli.positive,
        default=None,
        help="truncate the reference to this many seconds",
    )
    parser.add_argument(
        "--kd",
        type=cli.positive,
        default=None,
        help="override K_d of the collocated laws (the paper used 0.02, and 0.01 from 2023-10-19)",
    )
    parser.add_argument(
        "--disturbance",
        type=cli.world_name,
        choices=WORLDS,
        default=DEFAULT_WORLD,
        help=(
            "the world (hsa_core.sim.disturbance): 'calibrated' (the default: the material's world "
            "fitted to the real runs, docs/simulation.md), 'declared' (the hand-declared model), "
            "none, or 'shear' (the declared world with half the shear stiffness)"
        ),
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/experiments"))
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    cli.run_with_images(parser, args)
    if args.run is not None:
        given = [
            name
            for name, value in (
                ("--material", args.material),
                ("--controller", args.controller),
                ("--profile", args.profile),
                ("--rate", args.rate),
            )
            if value is not None
        ] + (["--trajectory"] if args.trajectory != "steps" else [])
        if given:
            parser.error(f"argument --run: the run sets its own {', '.join(given)}; leave them out")

    results = []
    for config in _configs(args):
        result = run_experiment(config, progress=not args.quiet)
        results.append(result)
        out = args.out / config.name
        out.mkdir(parents=True, exist_ok=True)
        result.log.save_npz(out / "log.npz")
        result.log.save_csv(out / "log.csv")
        if not args.no_figures:
            plotting.all_figures(
                result.log,
                out,
                phi_max=float(result.log.meta["phi_max"]),
                contour=args.trajectory != "steps",
                rmse=result.metrics.rmse,
            )
        for t_fail, failure in result.plan_failures:
            print(
                f"[{config.name}] planning failed at t = {t_fail:.2f} s: {failure.status.name}: "
                f"{failure.message}"
            )
    if not args.no_figures and len(results) > 1:
        plotting.overlay_figures(
            [r.log for r in results], args.out / "figures", [r.metrics.rmse for r in results]
        )
    print(metrics.format_summary([r.metrics for r in results]))
    print("\nnoise-free steady-state error (plant truth, mean over steps after the first):")
    for r in results:
        print(
            f"  {r.config.name:<24} {r.true_steady_state_error() * 1e3:6.3f} mm   (wall time "
            f"{r.wall_time:5.1f} s)"
        )
    print(f"\nlogs and figures in {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

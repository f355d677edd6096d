"""Why the simulated task-space PID limit-cycles (and P-satI-D overshoots): one world factor
switched off at a time.

Runs the offline experiment (hsa_core.sim.experiment.run_experiment, the reference the lockstep ROS
graph reproduces) on the FPU step list, truncated to ``--duration`` seconds, with the paper's gains,
the world ``--disturbance`` names (default the declared one; ``calibrated``: the FPU world fitted to
the real runs; noise seed 0) under the run ``--profile`` (default the lab's) and one factor of it
changed per row: measurement noise, measurement latency, actuation latency, the servo speed cap, the
plant/model mismatch, K_d, the 40 Hz control rate, the Savitzky–Golay derivative (replaced by the
plant's exact velocity) or given a 0.4 s window, all of the disturbance, the speed cap alone, and
the plant's hand-tuned damping x3; for P-satI-D also the paper's K_d = 0.01. Per run it reports
RMSE, e_ss (measured, mean over the steps after the first), overshoot, the peak-to-peak of the true
x over the last 2 s of each step after the first (mean and max), the dominant frequency of x − x_des
over the last 4 s of those steps (averaged Hann periodograms) and the range φ covers over the last 2
s. ``--full`` adds the full 110 s runs of ``--full-rows`` (default world, and the
September-estimator stand-in). ``linear_analysis`` adds the linearised PID x-loop (bending mode, SG
response, margins, the amplitude the servo speed cap allows; the lab loop only: 40 Hz,
Savitzky–Golay). Findings: docs/simulation.md (PID limit cycle). Writes
benchmarks/results/pid_limit_cycle.json or ``--out`` (after every run, so an interrupted run keeps
what it measured) with the command, world, profile and the machine's load. Usage: python
benchmarks/pid_limit_cycle.py --full  (all rows, both laws, 40 s, plus the 110 s runs; ~20 min on 2
loaded cores); [--laws pid] [--rows default,no_speed_cap] [--append] add to the existing JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import platform
import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from hsa_core.apps import robustness
from hsa_core.controller.control import default_gains
from hsa_core.jaxsetup import configure_jax
from hsa_core.model import kinematics, simulation
from hsa_core.model.dynamics import forward_dynamics_fn
from hsa_core.model.params import load_params
from hsa_core.runs.profiles import DEFAULT_PROFILE, RunProfile, VelocityEstimator, load_profile
from hsa_core.sensing.estimation import Estimate, derivative_coefficients
from hsa_core.sim import experiment
from hsa_core.sim.disturbance import DisturbanceModel, named_world
from hsa_core.sim.experiment import ExperimentResult, profile_config, run_experiment
from hsa_core.sim.world import MOCAP_PERIOD_NS, MocapSample, World
from hsa_core.task.trajectories import TimedReference, step_reference

ESTIMATOR_WINDOW = experiment.ESTIMATOR_WINDOW
"""The kinematics node's Savitzky–Golay window (samples), restored after every run."""
RESULTS = Path(__file__).resolve().parent / "results" / "pid_limit_cycle.json"
STEADY_WINDOW = 2.0
"""[s] window at the end of each step for the peak-to-peak and φ range (the e_ss window of
experiments.md §4)."""
SPECTRUM_WINDOW = 4.0
"""[s] window at the end of each step for the spectrum of x − x_des (0.25 Hz resolution)."""
MOCAP_PERIOD = MOCAP_PERIOD_NS * 1e-9
"""[s] motion-capture period (200 Hz)."""
MIN_FREQUENCY = 0.5
"""[Hz] lowest frequency considered for the dominant peak (below it: the step's slow
convergence)."""


@dataclass(frozen=True)
class Row:
    """One factor setting: label, what it changes, and how (world, gains, rate, exact
    derivative)."""

    name: str
    change: str
    disturbance: DisturbanceModel = field(default_factory=DisturbanceModel)
    kd: float | None = None  # None: the paper's K_d
    rate: float | None = None  # None: the profile's
    exact_derivative: bool = False
    estimator_window: int = experiment.ESTIMATOR_WINDOW


SG_ROWS = ("exact_derivative", "sg_window_80")
"""Rows that change the Savitzky–Golay estimator: meaningful only under a profile that uses it."""


def rows(world: DisturbanceModel) -> tuple[Row, ...]:
    """The factor rows, each one change of ``world`` (the run's named world) or of the loop."""
    ms = 1e3
    return (
        Row(
            "default",
            f"the world itself (noise, {world.measurement_latency * ms:g} ms mocap and "
            f"{world.actuation_latency * ms:g} ms actuation latency, mismatch, "
            f"{world.servo_max_speed:.2f} rad/s cap)",
            world,
        ),
        Row(
            "no_noise",
            "pose noise sigma = 0",
            dataclasses.replace(world, pose_noise_std=(0.0, 0.0, 0.0)),
        ),
        Row(
            "no_meas_latency",
            f"mocap latency {world.measurement_latency * ms:g} ms -> 0",
            dataclasses.replace(world, measurement_latency=0.0),
        ),
        Row(
            "no_act_latency",
            f"actuation latency {world.actuation_latency * ms:g} ms -> 0",
            dataclasses.replace(world, actuation_latency=0.0),
        ),
        Row(
            "no_speed_cap",
            f"servo speed cap {world.servo_max_speed:.2f} rad/s -> none",
            dataclasses.replace(world, servo_max_speed=math.inf),
        ),
        Row(
            "no_mismatch",
            "plant = model (stiffness 1, C_eps 1, sigma_a_eq offset 0; rod difference, shear "
            "strain offset 0, shear scale 1)",
            dataclasses.replace(
                world,
                stiffness_scale=1.0,
                elongation_scale=1.0,
                rest_strain_offset=0.0,
                rest_strain_difference=0.0,
                shear_strain_offset=0.0,
                shear_scale=1.0,
            ),
        ),
        Row("kd_zero", "K_d = 0 (P-I only)", world, kd=0.0),
        Row(
            "kd_0.01",
            "K_d = 0.01 (P-satI-D only: the paper's own remedy of 2023-10-19 against D-term "
            "oscillations)",
            world,
            kd=0.01,
        ),
        Row("rate_200", "control rate -> 200 Hz (integrator dt follows)", world, rate=200.0),
        Row(
            "exact_derivative",
            "SG derivative -> plant's exact velocity (no lag, no noise)",
            world,
            exact_derivative=True,
        ),
        Row(
            "all_off",
            "DisturbanceModel.none(): no noise, latency, mismatch or cap",
            DisturbanceModel.none(),
        ),
        Row(
            "cap_only",
            "DisturbanceModel.none() plus the world's speed cap",
            dataclasses.replace(DisturbanceModel.none(), servo_max_speed=world.servo_max_speed),
        ),
        Row(
            "sg_window_80",
            "SG window 20 -> 80 samples (0.4 s: the span of the September runs' 16-sample fit at "
            "40 Hz; a stand-in for that smoothing spline)",
            world,
            estimator_window=80,
        ),
        Row(
            "damping_x3",
            "plant damping constants x3 (hand-tuned in the paper, not identified)",
            dataclasses.replace(world, damping_scale=3.0 * world.damping_scale),
        ),
    )


_ee_velocity = jax.jit(lambda plant, q, q_dot: kinematics.end_effector_jacobian(plant, q) @ q_dot)


class _ExactDerivative:
    """Stand-in for the Savitzky–Golay estimator: the plant's exact [q_dot, chiee_dot] now (no lag,
    no noise)."""

    world: World | None = None

    def __init__(self, **_: object) -> None:
        """Accept the estimator's settings and ignore them."""

    def update(self, t: float, x: np.ndarray) -> Estimate:
        """Return the sample and the true velocity of the plant at the world's current instant."""
        world = _ExactDerivative.world
        q, q_dot = world.x[:3], world.x[3:]
        chiee_dot = _ee_velocity(world.plant, q, q_dot)
        return Estimate(
            np.asarray(x), np.concatenate([np.asarray(q_dot), np.asarray(chiee_dot)]), True, "exact"
        )


class _World(World):
    """World that registers itself for _ExactDerivative and, with zero mocap latency, hands a tick
    its own sample.

    hsa_core.sim.world.World draws the sample stamped t when it starts the interval after t, so with
    ``measurement_latency = 0`` run_experiment asks again and again for instant t and never advances
    (it hangs; reported to the lead). Here a sample due at the instant the world stops at is drawn
    there (the pose at t, available at t); the World's own draw for that stamp is dropped. Without
    zero latency nothing changes."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self._drawn_ns = -1
        _ExactDerivative.world = self

    def advance_to(self, t_ns: int) -> None:
        """Advance as World does, then draw the sample due now (zero latency only); drop duplicate
        stamps."""
        super().advance_to(t_ns)
        if self._sample_latency_ns == 0:
            self._samples = deque(s for s in self._samples if s.stamp_ns > self._drawn_ns)
            if self.t_ns % MOCAP_PERIOD_NS == 0 and self.t_ns > self._drawn_ns:
                chiee = self.disturbance.measure(self._rng, self.true_pose())
                self._samples.append(MocapSample(self.t_ns, self.t_ns, chiee))
                self._drawn_ns = self.t_ns

    def next_sample_ns(self) -> int:
        """As World's, skipping a stamp already drawn here."""
        t = super().next_sample_ns()
        return t + MOCAP_PERIOD_NS if not self._samples and t <= self._drawn_ns else t


@contextlib.contextmanager
def _exact_derivative() -> Iterator[None]:
    """Swap the experiment's estimator for the exact plant velocity for the duration of one run."""
    saved = experiment.SavitzkyGolayDifferentiator
    experiment.SavitzkyGolayDifferentiator = _ExactDerivative
    try:
        yield
    finally:
        experiment.SavitzkyGolayDifferentiator = saved
        _ExactDerivative.world = None


def truncated(reference: TimedReference, duration: float) -> TimedReference:
    """The reference cut to its first ``duration`` seconds (as hsa_experiment --duration does)."""
    keep = reference.t < duration
    return TimedReference(
        reference.t[keep], reference.p_des[keep], reference.name, min(duration, reference.duration)
    )


def oscillation(result: ExperimentResult) -> dict[str, float]:
    """Peak-to-peak of true x and φ range over the last 2 s, dominant frequency of x − x_des (steps
    ≥ 2)."""
    log = result.log
    x_true = result.true_chiee[:, 0]
    err = log.chiee_des[:, 0] - log.chiee[:, 0]
    dt = float(np.median(np.diff(log.t)))
    p2p, phi_lo, phi_hi, spectra = [], [], [], []
    for step in result.metrics.steps[1:]:
        last = (log.t >= step.t_end - STEADY_WINDOW) & (log.t < step.t_end)
        p2p.append(float(np.ptp(x_true[last])))
        phi_lo.append(float(np.min(log.phi_sat[last])))
        phi_hi.append(float(np.max(log.phi_sat[last])))
        window = (log.t >= step.t_end - SPECTRUM_WINDOW) & (log.t < step.t_end)
        e = err[window] - np.mean(err[window])
        spectra.append(np.abs(np.fft.rfft(e * np.hanning(len(e)))) ** 2)
    n = min(len(s) for s in spectra)
    power = np.mean([s[:n] for s in spectra], axis=0)
    freqs = np.fft.rfftfreq(2 * (n - 1), dt)[:n]
    band = freqs >= MIN_FREQUENCY
    peak = int(np.argmax(np.where(band, power, -1.0)))
    return {
        "p2p_x_mean_mm": 1e3 * float(np.mean(p2p)),
        "p2p_x_max_mm": 1e3 * float(np.max(p2p)),
        "dominant_frequency_hz": float(freqs[peak]),
        "peak_power_share": float(power[peak] / np.sum(power[band])),
        "phi_min_last2s_rad": float(np.min(phi_lo)),
        "phi_max_last2s_rad": float(np.max(phi_hi)),
        "phi_span_last2s_mean_rad": float(np.mean(np.asarray(phi_hi) - np.asarray(phi_lo))),
    }


def linear_analysis(world: DisturbanceModel, cycle_hz: float | None) -> dict[str, object]:
    """Linearised x-loop of the PID at φ = φ_max/2 on ``world``'s plant: mode, SG response,
    margins, and the rate-limit bound of a cycle at ``cycle_hz`` (left out without one).

    Approximate (continuous-time equivalent of the 40 Hz lab loop: zero-order hold as (1 −
    e^(−jωT))/(jωT), the newest mocap sample at a tick as old as the world's mocap latency rounded
    up to the 5 ms grid, the world's actuation latency, x-loop alone)."""
    model = load_params("fpu")
    plant = world.plant_params(model)
    sample_age = MOCAP_PERIOD * math.ceil(world.measurement_latency / MOCAP_PERIOD - 1e-9)
    phi0 = jnp.full(2, float(np.min(np.asarray(model.phi_max))) / 2.0)
    q_ddot = forward_dynamics_fn(plant)
    x0 = jnp.asarray(simulation.steady_state_rollout(plant, phi0)).at[3:].set(0.0)
    rhs = lambda x, phi: jnp.concatenate([x[3:], q_ddot(x[:3], x[3:], phi)])  # noqa: E731
    a = np.asarray(jax.jacfwd(rhs, 0)(x0, phi0))
    # u = (u_x, u_y) -> φ
    b = np.asarray(jax.jacfwd(rhs, 1)(x0, phi0)) @ np.array([[1.0, 1.0], [-1.0, 1.0]])
    c = np.asarray(jax.jacfwd(lambda x: kinematics.end_effector_pose(plant, x[:3]))(x0))[:2]
    eig = np.linalg.eigvals(a)
    mode = eig[np.argmin(np.where(eig.imag > 0, np.abs(eig), np.inf))]
    p_x = lambda w: (c @ np.linalg.solve(1j * w * np.eye(6) - a, b))[0, 0]  # noqa: E731  x / u_x [m/rad]
    n, period_mocap = experiment.ESTIMATOR_WINDOW, MOCAP_PERIOD
    coeffs = derivative_coefficients(np.arange(n) - (n - 1.0), experiment.ESTIMATOR_ORDER)
    tau = (np.arange(n) - (n - 1.0)) * period_mocap
    sg = lambda w: np.sum(coeffs * np.exp(1j * w * tau)) / period_mocap  # noqa: E731
    gains = default_gains("pid", "fpu")
    period = 1.0 / 40.0

    def loop(f: float, exact: bool, kd: float) -> complex:
        """Open-loop x-loop gain L(j2πf) (negative feedback; instability where L circles −1)."""
        w = 2.0 * math.pi * f
        derivative = (
            1j * w * np.exp(-1j * w * 0.004) if exact else sg(w) * np.exp(-1j * w * sample_age)
        )
        law = (gains.kp + gains.ki / (1j * w)) * np.exp(-1j * w * sample_age) + kd * derivative
        hold = (
            (1.0 - np.exp(-1j * w * period))
            / (1j * w * period)
            * np.exp(-1j * w * world.actuation_latency)
        )
        return p_x(w) * law * hold

    freqs = np.linspace(1.0, 19.9, 1891)
    cases = {}
    for name, exact, kd in (
        ("sg_derivative", False, gains.kd),
        ("exact_derivative", True, gains.kd),
        ("kd_zero", False, 0.0),
    ):
        values = np.array([loop(f, exact, kd) for f in freqs])
        phase = np.degrees(np.unwrap(np.angle(values)))
        crossing = np.where(np.diff(np.sign(phase + 180.0)))[0]
        k = int(crossing[0]) if len(crossing) else -1
        cases[name] = {
            "f_phase_180_hz": float(freqs[k]) if k >= 0 else None,
            "gain_at_phase_180": float(abs(values[k])) if k >= 0 else None,
            "gain_at_10hz": float(abs(loop(10.0, exact, kd))),
            "phase_at_10hz_deg": float(np.degrees(np.angle(loop(10.0, exact, kd)))),
        }
    analysis: dict[str, object] = {
        "operating_point": "FPU plant of the world, phi = phi_max/2 on both rods, at rest",
        "sample_age_ms": 1e3 * sample_age,
        "actuation_latency_ms": 1e3 * world.actuation_latency,
        "bending_mode_hz": float(abs(mode) / (2.0 * math.pi)),
        "bending_mode_damping_ratio": float(-mode.real / abs(mode)),
        "static_dx_dux_mm_per_rad": 1e3 * float(p_x(1e-6).real),
        "plant_gain_ratio_at_10hz": float(abs(p_x(2.0 * math.pi * 10.0)) / abs(p_x(1e-6))),
        "sg_gain_vs_ideal": {
            f"{f:g}_hz": float(abs(sg(2 * math.pi * f) / (2j * math.pi * f)))
            for f in (2, 5, 10, 12)
        },
        "sg_phase_vs_ideal_deg": {
            f"{f:g}_hz": float(np.degrees(np.angle(sg(2 * math.pi * f) / (2j * math.pi * f))))
            for f in (2, 5, 10, 12)
        },
        "loop": cases,
    }
    if cycle_hz is not None:
        # amplitude of a full-speed triangle at the cycle's frequency [rad]
        triangle = world.servo_max_speed / (4.0 * cycle_hz)
        analysis["rate_limit_bound"] = {
            "f_hz": cycle_hz,
            "max_sinusoid_amplitude_rad": world.servo_max_speed / (2.0 * math.pi * cycle_hz),
            "triangle_amplitude_rad": triangle,
            "x_p2p_predicted_mm": 1e3
            * 2.0
            * abs(p_x(2.0 * math.pi * cycle_hz))
            * 8.0
            / math.pi**2
            * triangle,
        }
    return analysis


def run_row(
    row: Row, law: str, reference: TimedReference, profile: RunProfile
) -> dict[str, object]:
    """Run one (factor, law) pair under ``profile`` (on _World) and summarise it."""
    gains = default_gains(law, "fpu")
    if row.kd is not None:
        gains = dataclasses.replace(gains, kd=row.kd)
    config = profile_config(
        profile, "fpu", law, reference=reference, disturbance=row.disturbance, gains=gains
    )
    if row.rate is not None:
        config = dataclasses.replace(config, rate=row.rate, integrator_dt=None)
    experiment.World, experiment.ESTIMATOR_WINDOW = _World, row.estimator_window
    try:
        with _exact_derivative() if row.exact_derivative else contextlib.nullcontext():
            result = run_experiment(config)
    finally:
        experiment.World, experiment.ESTIMATOR_WINDOW = World, ESTIMATOR_WINDOW
    m = result.metrics
    return {
        "row": row.name,
        "law": law,
        "change": row.change,
        "duration_s": reference.duration,
        "rmse_mm": 1e3 * m.rmse,
        "e_ss_mm": 1e3 * m.steady_state_error_mean,
        "e_ss_true_mm": 1e3 * result.true_steady_state_error(),
        "overshoot_percent": m.overshoot_percent_mean,
        "t_r_s": m.response_time_mean,
        "saturated_fraction": m.saturated_fraction,
        **oscillation(result),
        "wall_s": result.wall_time,
    }


def _table(records: list[dict[str, object]]) -> str:
    """Markdown table of the records."""
    lines = [
        "| law | row | RMSE [mm] | e_ss [mm] | overshoot [%] | p2p x mean / max [mm] | f [Hz] | φ "
        "last 2 s [rad] | sat. |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        lines.append(
            f"| {r['law']} | {r['row']} | {r['rmse_mm']:.2f} | {r['e_ss_mm']:.2f} | "
            f"{r['overshoot_percent']:.1f} "
            f"| {r['p2p_x_mean_mm']:.2f} / {r['p2p_x_max_mm']:.2f} | "
            f"{r['dominant_frequency_hz']:.2f} "
            f"| {r['phi_min_last2s_rad']:.2f}–{r['phi_max_last2s_rad']:.2f} "
            f"| {100 * r['saturated_fraction']:.0f} % |"
        )
    return "\n".join(lines)


def cycle_hz(runs: list[dict[str, object]]) -> float | None:
    """The dominant frequency of the PID's ``default`` row where it cycles (mean x p2p ≥ 1 mm),
    else None."""
    for r in runs:
        if r["row"] == "default" and r["law"] == "pid" and r["p2p_x_mean_mm"] >= 1.0:
            return float(r["dominant_frequency_hz"])
    return None


def main(argv: list[str] | None = None) -> None:
    """Run the selected rows for the selected laws, print a markdown table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--duration", type=float, default=40.0, help="truncate the FPU step list [s] (110 = all)"
    )
    parser.add_argument("--laws", default="pid,psatid")
    parser.add_argument("--rows", default=",".join(r.name for r in rows(DisturbanceModel())))
    parser.add_argument(
        "--full", action="store_true", help="also run the full 110 s experiment for --full-rows"
    )
    parser.add_argument(
        "--full-rows", default="default,sg_window_80", help="rows run at full length with --full"
    )
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--append", action="store_true", help="add the runs to the existing JSON")
    parser.add_argument(
        "--analysis-only",
        action="store_true",
        help="only (re)compute the linear analysis into the existing JSON",
    )
    # the FPU world the rows change (default the declared one, of pid_limit_cycle.json); the profile
    robustness.add_world_options(parser, world="declared")
    args = parser.parse_args(argv)
    profile = args.profile or load_profile(DEFAULT_PROFILE)
    world = named_world(args.disturbance, "fpu")
    table = {r.name: r for r in rows(world)}
    names = [name for name in args.rows.split(",") if name]
    if unknown := [name for name in names if name not in table]:
        parser.error(f"unknown row(s) {unknown}; choose from {list(table)}")
    sg = profile.velocity_estimator is VelocityEstimator.SAVITZKY_GOLAY_20
    if not sg and (off := [n for n in names if n in SG_ROWS]):
        parser.error(
            f"rows {off} change the Savitzky–Golay estimator; profile {profile.name} has none"
        )
    configure_jax()
    lab = sg and profile.rate == 40.0
    if args.analysis_only:
        doc = json.loads(args.out.read_text())
        doc["linear_analysis"] = linear_analysis(world, cycle_hz(doc["runs"])) if lab else None
        args.out.write_text(json.dumps(doc, indent=1))
        print(json.dumps(doc["linear_analysis"], indent=1))
        return
    started = time.perf_counter()
    selected = [table[name] for name in names]
    laws = args.laws.split(",")
    reference = truncated(step_reference("fpu"), args.duration)
    doc: dict[str, object] = {
        "what": __doc__.splitlines()[0],
        "command": " ".join([Path(sys.argv[0]).name, *(sys.argv[1:] if argv is None else argv)]),
        "machine": platform.node(),
        "date_utc": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()),
        "load_1min_at_start": os.getloadavg()[0],
        "material": "fpu",
        "world": args.disturbance,
        "profile": profile.name,
        "seed": world.seed,
        "duration_s": reference.duration,
        "gains": {law: dataclasses.asdict(default_gains(law, "fpu")) for law in laws},
        "linear_analysis": None,
        "runs": [],
        "full_runs": [],
    }
    if args.append:
        doc = json.loads(args.out.read_text())
    for law in laws:
        for row in selected:
            if row.name == "kd_0.01" and law == "pid":
                continue  # a collocated K_d; the PID's K_d has other units
            record = run_row(row, law, reference, profile)
            doc["runs"].append(record)
            print(_table([record]).splitlines()[-1], flush=True)
            args.out.write_text(json.dumps(doc, indent=1))
    if args.full:
        for law, row in ((law, table[name]) for name in args.full_rows.split(",") for law in laws):
            record = run_row(row, law, step_reference("fpu"), profile)
            doc["full_runs"].append(record)
            print(_table([record]).splitlines()[-1], flush=True)
            args.out.write_text(json.dumps(doc, indent=1))
    if lab:
        doc["linear_analysis"] = linear_analysis(world, cycle_hz(doc["runs"]))
    doc["wall_s"] = round(time.perf_counter() - started, 1)
    doc["load_1min_at_end"] = os.getloadavg()[0]
    args.out.write_text(json.dumps(doc, indent=1))
    print(_table(doc["runs"] + doc["full_runs"]))


if __name__ == "__main__":
    main()

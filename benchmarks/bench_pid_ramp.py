"""Why the robot's PID steps are ramps that overshoot: controller side or plant side?

The FPU PID run (20230925_092200) is the one furthest from its replay (docs/simulation.md, "What
each lead could gain at most"). The packaged runs hold the robot's commanded twists φ
(``<bag>_phi.csv``), so the two halves of the loop can be checked apart:

* **tick periods**: the spacing of the plotted samples (each one a controller tick) per run;
* **the law on the robot's own motion** (PID run): the task-space PID of p&c §3.5 (paper gains,
  φ^ss = φ_max/2, clip to [0, φ_max], integrator step 25 ms) stepped at the run's ticks on the
  robot's plotted p (linear between the plotted samples), the derivative from the September
  stand-in's cubic over 16 ticks; per step the integral state is set so that the law gives the
  robot's φ at its last φ sample before the step (the integral's value is not in the data). RMS
  of φ_law − φ_robot per rod, over windows after the step;
* **the replay's commanded φ against the robot's** (closed loop, own conditions, calibrated world),
  each step aligned at its own instant, as D does;
* **the robot's φ into the simulated world** (open loop): the robot's commanded φ (linear between
  its plotted samples) written at the run's ticks into ``World`` (the calibrated world and the
  run's plant); D by window against the robot's p and the time each reaches 10 … 100 % of the step;
* **what-ifs** (not conditions): the September driver's command queue (below), alone and with a
  scan of the world's actuation latency (``--latency-ms``), a first-order servo lag, the run's own
  tick period.

The driver-queue what-if models the September command path from the spec and the original code:
goals go out per motor only on change (p&c §7) as messages on reliable keep-last-10 topics
(reference_ros_graph.md §1, §3 ``qos_depth`` = 10, §6 item 3) to a one-thread driver that does one
blocking single write with a status round trip per message (p&c §8, graph §6 item 2) and serves the
controller's position polls in the same thread (one per tick here). Per cycle it takes one message
per non-empty topic, then one poll; ``--transaction-ms`` is the time of one bus transaction (16 ms:
the FTDI latency timer's default, p&c §8 "every read can wait up to 16 ms"; 8 ms for contrast). The
control node published the goals without waiting for the driver (hsa_actuation_base_node of
tud-cor-sr/ros2-hsa at 2e59515, the version of 2023-09-25), so the driver's backlog does not show in
the tick spacing.

Every replay here keeps the September command path of session 24, when this analysis was made:
11 ms of command latency and no command queue in the world (``SESSION_24_PATH``); the queue is this
bench's own what-if. Since session 25 the ``sep2023`` profile sends its goals through the same
queue (:mod:`hsa_core.sim.command_queue`), so its replays would otherwise queue twice.

    .venv/bin/python benchmarks/bench_pid_ramp.py [--out benchmarks/results/pid_ramp.json]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from hsa_core.jaxsetup import configure_jax

ROOT = Path(__file__).resolve().parents[1]
PID_RUN = "20230925_092200"
FPU_RUNS = (PID_RUN, "20230925_093236", "20230925_094023")
WINDOWS = ((0.0, 0.15), (0.15, 0.6), (0.6, 5.0), (5.0, 9.3))
LEVELS = (0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
GRID = np.arange(0.0, 9.3, 0.01)
DEPTH = 10
SESSION_24_PATH = {"command_queue": (0, 0.0), "command_latency": 0.011}
"""The ``sep2023`` command path this analysis was made with (module docstring)."""


def _interp(tt: np.ndarray, t: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Columns of ``a`` (n, k) sampled at ``tt``, linear."""
    return np.stack([np.interp(tt, t, a[:, i]) for i in range(a.shape[1])], axis=1)


def _robot_phi(real) -> tuple[np.ndarray, np.ndarray]:
    """(t, φ (n, 2)) of the robot's commanded twists as plotted."""
    return real.phi.t, np.stack([real.phi["phi1"], real.phi["phi2"]], axis=1)


def tick_period(t: np.ndarray) -> float:
    """[s] median spacing of consecutive plotted samples 20–55 ms apart (one tick; simplified
    stretches leave longer gaps)."""
    d = np.diff(t)
    return float(np.median(d[(d > 0.02) & (d < 0.055)]))


# ------------------------------------------------------------------ the law on the robot's motion
def law_on_robot(real, period: float, integrator_dt: float, kd: float | None = None) -> dict:
    """RMS [rad] of φ_law − φ_robot per window (module docstring), pooled over both rods and the
    steps whose pre-step φ is unsaturated; and of the robot's φ minus its pre-step value. ``kd``
    replaces the run's derivative gain."""
    from hsa_core.controller.control import (
        ControllerState,
        ControlReference,
        Measurement,
        task_space_pid,
    )
    from hsa_core.model.params import load_params
    from hsa_core.sensing.estimation import derivative_coefficients
    from hsa_core.sim.run_conditions import SPLINE_ORDER, SPLINE_WINDOW

    g = real.conditions.gains
    g = g if kd is None else dataclasses.replace(g, kd=kd)
    params = load_params(real.conditions.material)
    phi_ss = np.asarray(params.phi_max) / 2.0  # per rod
    mix = np.array([[1.0, 1.0], [-1.0, 1.0]])
    ticks = np.arange(0.0, real.t[-1], period)
    p = _interp(ticks, real.pee.t, np.stack([real.pee["px"], real.pee["py"]], axis=1) * 1e-3)
    p_des = real.p_des[np.clip(np.searchsorted(real.t, ticks, side="right") - 1, 0, None)]
    e = p_des - p
    # the September stand-in on uniform ticks: the cubic over the last SPLINE_WINDOW ticks
    c = derivative_coefficients(np.arange(1 - SPLINE_WINDOW, 1.0), SPLINE_ORDER) / period
    v = np.zeros_like(p)
    for k in range(SPLINE_WINDOW - 1, len(ticks)):
        v[k] = c @ p[k - SPLINE_WINDOW + 1 : k + 1]
    nan3 = np.full(3, np.nan)
    tr, phr = _robot_phi(real)
    sq: dict = {w: [] for w in WINDOWS}
    moved: dict = {w: [] for w in WINDOWS}
    used = 0
    for b in real.step_instants:
        j0 = np.where(tr < b - 0.005)[0][-1]
        if np.any(phr[j0] < 0.01) or np.any(phr[j0] > 2 * phi_ss - 0.01) or b - tr[j0] > 0.3:
            continue
        used += 1
        i0 = int(np.argmin(np.abs(ticks - tr[j0])))
        u0 = np.linalg.solve(mix, phr[j0] - phi_ss)
        e_int = (u0 - g.kp * e[i0] + g.kd * v[i0]) / g.ki
        tt, out = [], []
        state = ControllerState(e_int, np.zeros(2))
        for i in range(i0, len(ticks)):
            if ticks[i] > b + 9.3:
                break
            ref = ControlReference(np.append(p_des[i], 0.0), *[nan3] * 6)  # the PID reads chiee^d
            meas = Measurement(nan3, nan3, np.append(p[i], 0.0), np.append(v[i], 0.0))
            phi, state, _ = task_space_pid(params, g, ref, state, meas, integrator_dt)
            tt.append(ticks[i])
            out.append(np.asarray(phi))
        tt, out = np.asarray(tt), np.asarray(out)
        for w in WINDOWS:
            m = (tr >= b + w[0]) & (tr < b + w[1])
            sq[w] += list(((_interp(tr[m], tt, out) - phr[m]) ** 2).ravel())
            moved[w] += list(((phr[m] - phr[j0]) ** 2).ravel())
    return {
        "steps_used": used,
        "rms_rad": {f"{a}-{b}s": round(float(np.sqrt(np.mean(v))), 4) for (a, b), v in sq.items()},
        "robot_phi_change_rms_rad": {
            f"{a}-{b}s": round(float(np.sqrt(np.mean(v))), 4) for (a, b), v in moved.items()
        },
    }


# ------------------------------------------------------------------ the September command queue
class DriverQueue:
    """The September driver (module docstring): per-motor keep-last-``depth`` topics fed on change
    at the ticks, one server; per cycle one message per non-empty topic, then one pending poll (one
    request per tick; none with ``polls`` False); each transaction ``transaction`` [s].
    :meth:`tick` takes a tick's goals and returns the writes the driver makes until ``until`` [s]
    as (time [s], goal vector in force)."""

    def __init__(
        self, first: np.ndarray, transaction: float, depth: int = DEPTH, polls: bool = True
    ) -> None:
        self.transaction, self.depth, self.with_polls = transaction, depth, polls
        self.published = np.asarray(first).copy()  # what the control node last published
        self.in_force = np.asarray(first).copy()  # what the driver last wrote
        self.topics: list[list[tuple[float, int]]] = [[] for _ in first]
        self.polls = 0
        self.cursor = 0.0
        self.ages: list[float] = []

    def tick(self, t: float, goals: np.ndarray, until: float) -> list[tuple[float, np.ndarray]]:
        """Publish the changed goals of the tick at ``t`` and one poll; serve until ``until``."""
        for m, goal in enumerate(goals):
            if goal != self.published[m]:
                self.topics[m].append((t, int(goal)))
                del self.topics[m][: -self.depth]
                self.published[m] = goal
        self.polls = min(self.polls + 1, self.depth) if self.with_polls else 0
        self.cursor = max(self.cursor, t)
        writes = []
        while self.cursor < until and (self.polls or any(self.topics)):
            for m, topic in enumerate(self.topics):
                if topic:
                    stamp, goal = topic.pop(0)
                    self.in_force[m] = goal
                    self.ages.append(self.cursor - stamp)
                    writes.append((self.cursor, self.in_force.copy()))
                    self.cursor += self.transaction
            if self.polls:
                self.polls -= 1
                self.cursor += self.transaction
        return writes


def queued_world(transaction: float, period: float, polls: bool = True):
    """A ``World`` class whose goals go through a :class:`DriverQueue` (``write_goals`` at a tick
    publishes; the driver's writes reach the bus at their own times)."""
    from hsa_core.sim.world import World, seconds_to_ns

    class QueuedWorld(World):
        def write_goals(self, ticks, at_ns=None) -> None:
            at = self.t_ns if at_ns is None else int(at_ns)
            goals = np.asarray(ticks, dtype=np.int64)
            if not hasattr(self, "driver"):
                self.driver = DriverQueue(
                    np.rint(self.goal).astype(np.int64), transaction, polls=polls
                )
            for when, vector in self.driver.tick(at * 1e-9, goals, at * 1e-9 + period):
                super().write_goals(vector.astype(np.float64), seconds_to_ns(when))

    return QueuedWorld


@contextlib.contextmanager
def experiment_world(world_class):
    """``run_experiment`` builds its world from ``world_class`` inside the block."""
    from hsa_core.sim import experiment

    saved = experiment.World
    experiment.World = world_class
    try:
        yield
    finally:
        experiment.World = saved


# ------------------------------------------------------------------ comparisons
def _aligned(t: np.ndarray, p: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(10, len(GRID), k): ``p`` after each of steps 1–10."""
    return np.asarray([_interp(GRID + s, t, p) for s in starts[:10]])


def window_rms(sim: np.ndarray, robot: np.ndarray) -> dict:
    """RMS ‖sim − robot‖ over the aligned steps, per window and over all of it."""
    sq = np.sum((sim - robot) ** 2, axis=-1)
    out = {
        f"{a}-{b}s": float(np.sqrt(np.mean(sq[:, (GRID >= a) & (GRID < b)]))) for a, b in WINDOWS
    }
    out["all"] = float(np.sqrt(np.mean(sq)))
    return out


def progress_times(p: np.ndarray, start: np.ndarray, p_des: np.ndarray) -> np.ndarray:
    """[s] first aligned time the progress along the step reaches each of LEVELS (NaN: never)."""
    d = p_des - start
    s = (p - start) @ d / (d @ d)
    return np.array([GRID[np.argmax(s >= lv)] if np.any(s >= lv) else np.nan for lv in LEVELS])


def open_loop(real, world, period: float, transaction: float | None, polls: bool = True) -> tuple:
    """The robot's commanded φ into the run's world at ``period`` ticks → (t, p (n, 2), ages)."""
    from hsa_core.model.wiring import load_wiring
    from hsa_core.sim.experiment import replay_config
    from hsa_core.sim.run_conditions import plant_params
    from hsa_core.sim.world import World, seconds_to_ns

    config = dataclasses.replace(replay_config(real), disturbance=world, **SESSION_24_PATH)
    model = config.model()
    motor_map = load_wiring().motor_map(model)
    cls = World if transaction is None else queued_world(transaction, period, polls)
    w = cls(plant_params(model, config.payload), config.world(), motor_map)
    tr, phr = _robot_phi(real)
    ticks = np.arange(0.0, real.t[-1], period)
    out, newest = [], None
    for t in ticks:
        ns = seconds_to_ns(t)
        w.advance_to(ns)
        for sample in w.take_samples(ns):
            newest = sample.chiee
        out.append(newest[:2].copy() if newest is not None else np.full(2, np.nan))
        phi = np.clip(_interp(np.array([t]), tr, phr)[0], 0.0, motor_map.phi_max)
        w.write_goals(motor_map.goal_ticks(phi), ns)
    ages = np.asarray(getattr(getattr(w, "driver", None), "ages", [0.0]))
    return ticks, np.asarray(out), ages


def compare_open_loop(real, t: np.ndarray, p: np.ndarray) -> dict:
    """D by window and progress lags (robot − replay, median over steps) of an open-loop replay."""
    starts = real.step_instants
    robot = _aligned(real.t, real.p, starts)
    sim = _aligned(t, p, starts)
    lags = []
    for k, s in enumerate(starts[:10]):
        p_des = real.p_des[np.searchsorted(real.t, s + 0.05)]
        lags.append(
            progress_times(robot[k], robot[k][0], p_des)
            - progress_times(sim[k], robot[k][0], p_des)
        )
    return {
        "D_mm": {k: round(v * 1e3, 3) for k, v in window_rms(sim, robot).items()},
        "progress_lag_robot_minus_replay_s": dict(
            zip([str(v) for v in LEVELS], np.round(np.nanmedian(lags, axis=0), 3).tolist())
        ),
    }


def closed_loop(real, world, transaction: float | None = None, **config) -> dict:
    """The run replayed with its own conditions in ``world`` (offline experiment), optionally with
    the driver queue: D (sim_to_real), D by window, the commanded φ against the robot's by window
    and the progress times of sim and robot."""
    from hsa_core.analysis import sim_to_real
    from hsa_core.runs.reference import step_instants
    from hsa_core.sim.experiment import replay_config, run_experiment
    from hsa_core.sim.world import World

    cfg = dataclasses.replace(replay_config(real), disturbance=world, **SESSION_24_PATH, **config)
    cls = World if transaction is None else queued_world(transaction, 1.0 / cfg.rate)
    started = time.perf_counter()
    with experiment_world(cls):
        log = run_experiment(cfg).log
    wall = time.perf_counter() - started
    sim = sim_to_real.StepRun.of_log(log, 110.0)
    robot = sim_to_real.StepRun(real.t, real.p, real.p_des, 110.0)
    c = sim_to_real.compare(sim, robot)
    s_starts = step_instants(log.t, log.chiee_des[:, :2])
    r_starts = real.step_instants
    tr, phr = _robot_phi(real)
    phi_sim = _aligned(log.t, log.phi_sat, s_starts)
    phi_robot = _aligned(tr, phr, r_starts)
    p_sim, p_robot = sim_to_real.aligned_responses(sim), sim_to_real.aligned_responses(robot)
    times_sim, times_robot = [], []
    for k, s in enumerate(r_starts[:10]):
        p_des = real.p_des[np.searchsorted(real.t, s + 0.05)]
        times_sim.append(progress_times(p_sim[k], p_sim[k][0], p_des))
        times_robot.append(progress_times(p_robot[k], p_robot[k][0], p_des))
    levels = [str(v) for v in LEVELS]
    return {
        "D_mm": round(c.deviation * 1e3, 3),
        "D_per_step_mm": np.round(sim_to_real.step_deviations(sim, robot) * 1e3, 2).tolist(),
        "D_by_window_mm": {k: round(v * 1e3, 3) for k, v in window_rms(p_sim, p_robot).items()},
        "phi_sim_minus_robot_rms_rad": {
            k: round(v / np.sqrt(2.0), 4) for k, v in window_rms(phi_sim, phi_robot).items()
        },
        "progress_time_median_s": {
            "sim": dict(zip(levels, np.round(np.nanmedian(times_sim, 0), 3).tolist())),
            "robot": dict(zip(levels, np.round(np.nanmedian(times_robot, 0), 3).tolist())),
        },
        "overshoot_median": {
            name: round(float(np.median(sim_to_real.overshoots(run))) * 1e3, 3)
            for name, run in (("sim", sim), ("robot", robot))
        },
        "wall_s": round(wall, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "benchmarks" / "results" / "pid_ramp.json"
    )
    parser.add_argument("--transaction-ms", type=float, nargs="+", default=[16.0, 8.0])
    parser.add_argument(
        "--latency-ms",
        type=int,
        nargs="*",
        default=[50, 70, 90],
        help="the world's actuation latency with the 16 ms queue (closed loop; a what-if scan)",
    )
    args = parser.parse_args()
    configure_jax()
    from hsa_core.runs import reference
    from hsa_core.sim.disturbance import calibrated_world, rest_world

    started = time.perf_counter()
    load0 = os.getloadavg()[0]
    runs = {bag: reference.load_run(bag) for bag in FPU_RUNS}
    calibrated, rest = calibrated_world("fpu"), rest_world("fpu")
    doc: dict = {"what": __doc__.split("\n\n")[0], "tick_period_s": {}}
    for bag, real in runs.items():
        doc["tick_period_s"][bag] = {
            "pee": round(tick_period(real.pee.t), 4),
            "phi": round(tick_period(real.phi.t), 4),
            "profile": real.conditions.profile.control_period_ms * 1e-3,
        }
        print(bag, "tick period", doc["tick_period_s"][bag], flush=True)
    pid = runs[PID_RUN]
    own = round(tick_period(pid.phi.t), 3)
    doc["law_on_robot_motion"] = {
        f"period {period * 1e3:.0f} ms, integrator {idt * 1e3:.0f} ms": law_on_robot(
            pid, period, idt
        )
        for period, idt in ((0.036, 0.025), (own, 0.025), (own, own), (0.036, 0.036))
    }
    for kd in (0.0, 0.5):  # the launch file committed before the run had 0.5, the logbook 0.25
        doc["law_on_robot_motion"][f"period {own * 1e3:.0f} ms, integrator 25 ms, K_d {kd}"] = (
            law_on_robot(pid, own, 0.025, kd)
        )
    print(json.dumps(doc["law_on_robot_motion"], indent=1), flush=True)
    doc["open_loop"] = {}
    for bag in FPU_RUNS[:2]:
        real = runs[bag]
        period = round(tick_period(real.phi.t), 3)
        cases = {"calibrated": (calibrated, None, True)}
        for ms in args.transaction_ms:
            cases[f"calibrated + queue {ms:g} ms"] = (calibrated, ms * 1e-3, True)
            cases[f"rest world + queue {ms:g} ms"] = (rest, ms * 1e-3, True)
        cases["calibrated + queue 16 ms, no polls"] = (calibrated, 0.016, False)
        for name, (world, tx, polls) in cases.items():
            t, p, ages = open_loop(real, world, period, tx, polls)
            row = compare_open_loop(real, t, p)
            row["write_age_s"] = {
                "median": round(float(np.median(ages)), 3),
                "p90": round(float(np.percentile(ages, 90)), 3),
                "max": round(float(np.max(ages)), 3),
            }
            doc["open_loop"][f"{bag}: {name}"] = row
            print(bag, name, json.dumps(row), flush=True)
    doc["closed_loop"] = {}
    for bag in FPU_RUNS:
        real = runs[bag]
        cases = {
            "calibrated": dict(world=calibrated),
            "calibrated + queue 16 ms": dict(world=calibrated, transaction=0.016),
            "rest world + queue 16 ms": dict(world=rest, transaction=0.016),
            **{
                f"calibrated, actuation latency {ms} ms + queue 16 ms": dict(
                    world=dataclasses.replace(calibrated, actuation_latency=ms * 1e-3),
                    transaction=0.016,
                )
                for ms in args.latency_ms
            },
            "calibrated, servo time constant 0.15 s": dict(
                world=dataclasses.replace(calibrated, servo_time_constant=0.15)
            ),
            "calibrated, servo time constant 0.3 s": dict(
                world=dataclasses.replace(calibrated, servo_time_constant=0.3)
            ),
        }
        if bag == PID_RUN:
            cases[f"calibrated, tick period {own * 1e3:.0f} ms"] = dict(
                world=calibrated, rate=1.0 / own
            )
        for name, kw in cases.items():
            row = closed_loop(real, **kw)
            doc["closed_loop"][f"{bag}: {name}"] = row
            print(bag, name, json.dumps(row), flush=True)
    doc["machine"] = {
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "load_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
        "wall_s": round(time.perf_counter() - started, 1),
    }
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

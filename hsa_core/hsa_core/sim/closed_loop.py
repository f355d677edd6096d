"""The offline experiment as one pure JAX function: jit-able, vmap-able over plants, gains and noise
(no ROS).

:func:`rollout` runs the timeline of :mod:`hsa_core.sim.experiment` on the world of
:mod:`hsa_core.sim.world` — 1 ms grid, plant integrated with two RK4 steps per interval, MX-28 speed
cap, goals effective after the actuation latency, 200 Hz mocap with latency and noise, closed-form
IK, causal Savitzky–Golay, the control law with its integrators and saturation, goal ticks truncated
towards zero — as ``lax.scan`` over the control ticks (``fori_loop`` over the 1 ms instants inside).
The world's part is the world's own code: each interval is :func:`hsa_core.sim.world.interval_fn`,
the start :func:`~hsa_core.sim.world.hanging_at_rest`, a sample
:func:`~hsa_core.sim.world.mocap_sample`, the goal ticks ``MotorMap.goal_offsets``. At each instant,
as in the experiment: the tick (if one is due) runs first, then the samples that became available
reach the estimator, then the world runs one interval; whether an instant takes or delivers a sample
depends on the instant alone, so that work is a branch (``lax.cond``, which ``vmap`` keeps a branch)
and the other instants only move the servos and integrate the plant. The setpoints come from the
planner before the loop (:func:`prepare`); a tick uses the newest one planned strictly before it. Of
controller_node's supervision (:mod:`hsa_core.controller.control_loop`, which ``run_experiment``
runs) it models the fault-free path only: every tick with a setpoint and a state tracks (true while
mocap latency + 5 ms stays below stale_timeout).

What varies per run is an argument (a pytree, so ``jax.vmap`` batches it): the plant's parameters
(with its payload), the gains, the noise sequence, the servo speed and time constant, the actuation
latency. What shapes the loop is static (:class:`LoopSpec`): law, rate, mocap latency, length,
velocity estimator (the September 2023 stand-in of :mod:`hsa_core.runs.profiles` takes the newest
state into its 16-sample fit at every tick, on the true stamps:
:func:`hsa_core.sim.run_conditions.tick_take` and ``tick_rates`` traced, the functions
``run_experiment`` runs in numpy). For the same :class:`~hsa_core.sim.experiment.ExperimentConfig`
the metrics equal ``run_experiment``'s (test: tests/core/test_closed_loop.py).
"""

from __future__ import annotations

import dataclasses
import functools
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from hsa_core.analysis import metrics
from hsa_core.controller import control
from hsa_core.controller.control import CollocatedGains, ControllerKind, EeIntegralGains, PidGains
from hsa_core.model import kinematics
from hsa_core.model.actuation import MotorMap
from hsa_core.model.params import HsaParams
from hsa_core.model.wiring import load_wiring
from hsa_core.runs.profiles import VelocityEstimator
from hsa_core.sensing.estimation import derivative_coefficients
from hsa_core.sim import command_queue
from hsa_core.sim.experiment import ESTIMATOR_ORDER, ESTIMATOR_WINDOW, ExperimentConfig
from hsa_core.sim.run_conditions import (
    SPLINE_WINDOW,
    TickWindow,
    plant_params,
    tick_rates,
    tick_take,
    tick_window,
)
from hsa_core.sim.world import (
    GRID_NS,
    MOCAP_PERIOD_NS,
    hanging_at_rest,
    interval_fn,
    mocap_sample,
    seconds_to_ns,
    servo_speed,
    world_params,
)
from hsa_core.task.planning import Planner
from hsa_core.task.sequencer_timing import first_point_ns
from hsa_core.task.trajectories import step_reference

MS = GRID_NS
MOCAP_MS = MOCAP_PERIOD_NS // GRID_NS


@dataclasses.dataclass(frozen=True)
class LoopSpec:
    """What shapes the loop (static under jit): law, rate, mocap latency [ms], number of ticks,
    metrics window, velocity estimator."""

    kind: ControllerKind
    gravity_cancellation: bool
    ee_integral: EeIntegralGains | None
    period_ms: int
    measurement_latency_ms: int
    n_ticks: int
    first_tick: int  # index of the first tick that sends a command (t = 0 of the metrics)
    n_eval: int  # ticks in the metrics window (reference.duration)
    motor_map: (
        MotorMap  # the robot's wiring; its phi_max is the command clip, the driver's [0, phi_max]
    )
    dt: float  # [s] the integrators' step: the config's integrator_dt, else 1/rate
    velocity_estimator: VelocityEstimator = VelocityEstimator.SAVITZKY_GOLAY_20
    goal_slots: int = 2  # goals in flight: an actuation latency up to goal_slots - 1 periods
    queue_depth: int = 0  # the command queue's depth (0: goals written at the tick)
    transaction_ms: int = 0  # its transaction time


class LoopInputs(NamedTuple):
    """What may differ between runs (batch any leaf with ``jax.vmap``)."""

    plant: HsaParams  # the simulated plant
    gains: CollocatedGains | PidGains
    noise: Array  # (n_samples, 3) mocap noise [m, m, rad], sample k stamped at 5k ms
    servo_speed: Array  # [ticks per 1 ms interval]
    servo_lag: Array | None = None  # [s] WorldParams.servo_lag; None only in axes
    actuation_latency_ms: Array | None = None  # [ms] tick → goal in force; None only in axes


class LoopConstants(NamedTuple):
    """What is the same for every run of a batch: the controller's model and the planned
    setpoints."""

    model: HsaParams
    refs: control.ControlReference  # stacked per planned setpoint
    ref_index: Array  # (n_ticks,) setpoint active at each tick, -1: none yet


class TickLog(NamedTuple):
    """Per tick: whether the law ran, measured and desired EE pose, command and saturation, the
    plant's true pose."""

    ran: Array
    chiee: Array
    chiee_des: Array
    phi_cmd: Array
    saturated: Array
    true_chiee: Array


class _Carry(NamedTuple):
    x: Array  # plant state [q, q_dot]
    position: Array  # shaft positions [ticks]
    goal: Array  # goal in force [ticks]
    pending: Array  # (goal_slots, motors) goals written, by write count mod goal_slots [ticks]
    pending_at: Array  # (goal_slots,) [ms] when each takes effect (-1: none)
    writes: Array  # goals written so far
    queue: command_queue.QueueState | None  # the command queue (None: none)
    window: Array  # (N, 6) estimator window [q, chiee], oldest first
    stamps: Array  # (N,) their stamps [s]
    count: Array  # samples taken by the estimator
    ctrl: Array  # [e_int, z_ee]
    samples: Array  # (Q, 3) recent noisy poses, by sample index mod Q
    newest: Array  # (6,) the newest delivered [q, chiee] (the September estimator's input)
    newest_stamp: Array  # [s] its stamp (-inf: none yet)


def prepare(
    config: ExperimentConfig, model: HsaParams | None = None
) -> tuple[LoopSpec, LoopInputs, LoopConstants]:
    """The loop of ``config`` (as :func:`hsa_core.sim.experiment.run_experiment` runs it): spec,
    inputs and constants.

    ``model`` is the controller's model, which plans the setpoints (default: ``config.model()``)."""
    if config.mocap_outages:
        raise ValueError(
            "the batched loop models fault-free runs only: mocap_outages needs run_experiment"
        )
    model = config.model() if model is None else model
    reference = config.reference or step_reference(config.material)
    period_ns = seconds_to_ns(1.0 / config.rate)
    if period_ns % GRID_NS or period_ns < GRID_NS:
        raise ValueError(f"rate must divide 1000 Hz (the world's 1 ms grid), got {config.rate}")
    dist = config.world()
    lat_m, lat_a = (seconds_to_ns(v) for v in (dist.measurement_latency, dist.actuation_latency))
    if lat_m % GRID_NS or lat_a % GRID_NS:
        raise ValueError("latencies must be whole milliseconds")
    planner = Planner(model, config.planner)
    s0 = first_point_ns(config.start_delay)
    warm = len(reference) > 20
    planned = []  # (planned at [ns], reference)
    for k, t in enumerate(reference.t):
        result = planner.plan(reference.p_des[k], warm_start=warm)
        if result.success:
            ref = control.make_reference(model, result.setpoint, ee_integral=config.ee_integral)
            planned.append((s0 + seconds_to_ns(float(t)), ref))
    if not planned:
        raise RuntimeError(f"{config.name}: no setpoint could be planned")
    at_ticks = config.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    if at_ticks:  # the 16th tick after the first sample's delivery (strictly before) has a state
        ready_ns = (lat_m // period_ns + SPLINE_WINDOW) * period_ns - 1
    else:  # the instant the SG window's 20th sample is delivered
        ready_ns = (ESTIMATOR_WINDOW - 1) * MOCAP_PERIOD_NS + lat_m
    first = next(j for j in range(1, 10**7) if j * period_ns > max(ready_ns, planned[0][0]))
    n_eval = int(np.ceil(seconds_to_ns(reference.duration) / period_ns))
    n_ticks = first + n_eval
    tick_ns = np.arange(n_ticks) * period_ns
    at = np.array([p[0] for p in planned])
    ref_index = np.searchsorted(at, tick_ns, side="left") - 1  # planned strictly before the tick
    refs = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *[p[1] for p in planned])
    kind = ControllerKind(config.controller)
    gains = config.gains or control.default_gains(kind, config.material)
    ee = control.EeIntegralGains() if config.ee_integral else None
    spec = LoopSpec(
        kind,
        kind is ControllerKind.PSATID_GC,
        ee,
        period_ns // GRID_NS,
        lat_m // GRID_NS,
        n_ticks,
        first,
        n_eval,
        load_wiring().motor_map(model),
        1.0 / config.rate if config.integrator_dt is None else config.integrator_dt,
        config.velocity_estimator,
        goal_slots_for(lat_a // GRID_NS, period_ns // GRID_NS, dist.command_transaction_ms),
        dist.command_queue_depth,
        dist.command_transaction_ms,
    )
    inputs = LoopInputs(
        dist.plant_params(plant_params(model, config.payload)),
        gains,
        jnp.asarray(noise(dist, spec)),
        jnp.asarray(servo_speed(dist.servo_max_speed)),
        jnp.asarray(dist.servo_time_constant),
        jnp.asarray(lat_a // GRID_NS),
    )
    return spec, inputs, LoopConstants(model, refs, jnp.asarray(ref_index))


def goal_slots_for(latency_ms: int, period_ms: int, transaction_ms: int = 0) -> int:
    """The goals in flight at once with an actuation latency of ``latency_ms`` at a ``period_ms``
    period: one write per tick, or with a command queue one per ``transaction_ms`` at most,
    scheduled up to a period and a cycle (4 writes and a poll) ahead."""
    if transaction_ms:
        return (latency_ms + period_ms + 5 * transaction_ms) // transaction_ms + 2
    return latency_ms // period_ms + 2


def noise(disturbance, spec: LoopSpec, seed: int | None = None) -> np.ndarray:
    """The mocap noise of a run, drawn as the world draws it (one seeded generator, sample by
    sample)."""
    rng = np.random.default_rng(disturbance.seed if seed is None else seed)
    n = spec.n_ticks * spec.period_ms // MOCAP_MS + 2
    std = np.asarray(disturbance.pose_noise_std, dtype=np.float64)
    return np.array([rng.normal(0.0, 1.0, 3) * std for _ in range(n)])


def rollout(spec: LoopSpec, inputs: LoopInputs, constants: LoopConstants) -> TickLog:
    """Run the closed loop; one TickLog row per control tick (see the module docstring). Pure; jit
    with ``spec`` static (:func:`compiled`)."""
    plant, model = inputs.plant, constants.model
    motor_map = spec.motor_map
    world = world_params(plant, motor_map, inputs.servo_speed, inputs.servo_lag)
    interval = interval_fn(world)
    neutral = world.neutral
    at_ticks = spec.velocity_estimator is VelocityEstimator.SMOOTHING_SPLINE_16
    n_window = SPLINE_WINDOW if at_ticks else ESTIMATOR_WINDOW
    coeffs = jnp.asarray(
        derivative_coefficients(
            np.arange(ESTIMATOR_WINDOW) - (ESTIMATOR_WINDOW - 1.0), ESTIMATOR_ORDER
        )
    )
    queue = max(2, -(-spec.measurement_latency_ms // MOCAP_MS) + 2)
    lat_m, lat_a, period = spec.measurement_latency_ms, inputs.actuation_latency_ms, spec.period_ms

    def sample(samples: Array, x: Array, k: Array) -> Array:
        """Take mocap sample k (the pose at its stamp plus its noise) into the queue."""
        return samples.at[k % queue].set(mocap_sample(plant, x, inputs.noise[k]))

    def deliver(window: Array, stamps: Array, samples: Array, ts: Array) -> tuple[Array, Array]:
        """Hand the sample stamped ts [ms] to the estimator: its IK and pose enter the window."""
        chiee = samples[(ts // MOCAP_MS) % queue]
        z = jnp.concatenate([kinematics.inverse_kinematics(model, chiee), chiee])
        stamp = (ts * MS) * 1e-9  # [s] as the estimator gets it: (stamp − origin) · 1e-9, origin 0
        return jnp.concatenate([window[1:], z[None]]), jnp.concatenate([stamps[1:], stamp[None]])

    def instant(c: _Carry, t: Array) -> _Carry:
        """Samples at instant t (taken; handed to the estimator once available), then the interval
        [t, t + 1 ms)."""
        samples = jax.lax.cond(
            t % MOCAP_MS == 0, sample, lambda s, *_: s, c.samples, c.x, t // MOCAP_MS
        )
        ts = t - lat_m
        available = (ts >= 0) & (ts % MOCAP_MS == 0)
        if at_ticks:  # the sample is kept as the newest; the estimator takes it at the next tick
            newest, newest_stamp = jax.lax.cond(
                available,
                deliver,
                lambda w, s, *_: (w, s),
                c.newest[None],
                c.newest_stamp[None],
                samples,
                ts,
            )
            window, stamps, count = c.window, c.stamps, c.count
            newest, newest_stamp = newest[0], newest_stamp[0]
        else:
            window, stamps = jax.lax.cond(
                available, deliver, lambda w, s, *_: (w, s), c.window, c.stamps, samples, ts
            )
            count, newest, newest_stamp = c.count + available, c.newest, c.newest_stamp
        effective = (c.pending_at >= 0) & (c.pending_at <= t)  # the newest of them is in force
        newest_goal = jnp.argmax(jnp.where(effective, c.pending_at, -1))
        goal = jnp.where(jnp.any(effective), c.pending[newest_goal], c.goal)
        pending_at = jnp.where(effective, -1, c.pending_at)
        x, moved = interval(c.x, c.position, goal, True)
        return c._replace(
            x=x,
            position=moved,
            goal=goal,
            pending_at=pending_at,
            window=window,
            stamps=stamps,
            count=count,
            samples=samples,
            newest=newest,
            newest_stamp=newest_stamp,
        )

    def tick(c: _Carry, j: Array) -> tuple[_Carry, TickLog]:
        """The instants since the previous tick (from t = 0 for the first), then control tick j at
        t = j·period: the instant is traced once, the instants after the last tick, which no log row
        sees, are not run."""
        t = j * period
        c = jax.lax.fori_loop(t - period, t, lambda i, cc: instant(cc, i), c)
        if at_ticks:  # the September stand-in: the newest state enters its fit at every tick
            taken, _ = tick_take(
                TickWindow(c.window, c.stamps, c.count),
                c.newest_stamp,
                c.newest,
                period * MS * 1e-9,
                jnp,
            )
            c = c._replace(window=taken.z, stamps=taken.stamps, count=taken.count)
        ref_i = constants.ref_index[j]
        run = (ref_i >= 0) & (c.count >= n_window)
        ref = jax.tree_util.tree_map(lambda a: a[jnp.maximum(ref_i, 0)], constants.refs)
        if at_ticks:  # run only once the window is ready: the same condition
            derivative, _ = tick_rates(TickWindow(c.window, c.stamps, c.count), jnp)
        else:
            derivative = coeffs @ c.window / ((c.stamps[-1] - c.stamps[0]) / (n_window - 1))
        meas = control.Measurement(
            c.window[-1, :3], derivative[:3], c.window[-1, 3:], derivative[3:]
        )
        state = control.ControllerState(c.ctrl[:2], c.ctrl[2:])
        tick_dt = spec.dt
        if spec.kind is ControllerKind.PID:
            phi_cmd, new, info = control.task_space_pid(
                model, inputs.gains, ref, state, meas, tick_dt
            )
        else:
            phi_cmd, new, info = control.p_sati_d(
                model,
                inputs.gains,
                ref,
                state,
                meas,
                tick_dt,
                gravity_cancellation=spec.gravity_cancellation,
                ee_integral=spec.ee_integral,
            )
        ctrl = jnp.clip(
            jnp.concatenate([new.e_int, new.z_ee]), -control.INTEGRAL_LIMIT, control.INTEGRAL_LIMIT
        )
        phi = jnp.clip(phi_cmd, 0.0, spec.motor_map.phi_max)
        goal = neutral + motor_map.goal_offsets(phi, jnp)
        true_chiee = kinematics.end_effector_pose(plant, c.x[:3])
        log = TickLog(run, meas.chiee, ref.chiee_des, phi_cmd, info.saturated, true_chiee)
        c = c._replace(ctrl=jnp.where(run, ctrl, c.ctrl))
        if spec.queue_depth:
            return serve(c, run, goal, t), log
        return written(c, run, goal, t), log

    def written(c: _Carry, write: Array, goal: Array, at: Array) -> _Carry:
        """Where ``write``: ``goal`` written at ``at`` [ms], in force after the latency."""
        slot = c.writes % spec.goal_slots
        return c._replace(
            pending=c.pending.at[slot].set(jnp.where(write, goal, c.pending[slot])),
            pending_at=c.pending_at.at[slot].set(jnp.where(write, at + lat_a, c.pending_at[slot])),
            writes=c.writes + write,
        )

    def serve(c: _Carry, run: Array, goal: Array, t: Array) -> _Carry:
        """The command queue: the tick at t publishes ``goal`` (where ``run``), then the driver's
        cycles that start before the next tick write theirs (at most one per transaction)."""
        published = command_queue.publish(c.queue, goal, t, jnp)
        queue = jax.tree_util.tree_map(lambda a, b: jnp.where(run, a, b), published, c.queue)
        for _ in range(-(-period // spec.transaction_ms)):
            active = command_queue.has_work(queue, jnp) & (queue.cursor < t + period)
            after, done = command_queue.cycle(queue, spec.transaction_ms, jnp)
            queue = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), after, queue)
            for m in range(len(neutral)):
                c = written(c, active & done.wrote[m], done.vectors[m], done.at[m])
        return c._replace(queue=queue)

    window = (
        tick_window(jnp)
        if at_ticks
        else TickWindow(jnp.zeros((n_window, 6)), jnp.full(n_window, -1.0), jnp.asarray(0))
    )
    c = _Carry(
        hanging_at_rest(plant),
        neutral,
        neutral,
        jnp.tile(neutral, (spec.goal_slots, 1)),
        jnp.full(spec.goal_slots, -1),
        jnp.asarray(0),
        command_queue.initial(neutral, spec.queue_depth, jnp) if spec.queue_depth else None,
        *window,
        jnp.zeros(4),
        jnp.zeros((queue, 3)),
        jnp.zeros(6),
        jnp.asarray(-jnp.inf),
    )
    _, log = jax.lax.scan(tick, c, jnp.arange(1, spec.n_ticks))
    return log


XLA_OPTIONS = {
    "xla_cpu_enable_fast_math": True,
    "xla_cpu_fast_math_honor_nans": True,
    "xla_cpu_fast_math_honor_infs": True,
    "xla_cpu_fast_math_honor_division": True,
    "xla_cpu_fast_math_honor_functions": True,
}
"""XLA options of every compilation of the loop: on the CPU, floating-point reassociation and
contraction (FMA) only; NaN, inf, division and library functions stay exact. Reassociation lets LLVM
vectorise the dynamics' sums over the 9 mass points, which the strict order keeps scalar: ~1.5x the
runs per minute (benchmarks/results/closed_loop.json). The loop's metrics still equal the
experiment's to ~1e-14 (tests/core/test_closed_loop.py); other backends do not read ``xla_cpu_``
options."""

compiled = jax.jit(rollout, static_argnums=0, compiler_options=XLA_OPTIONS)
"""``rollout`` compiled (``spec`` static); :func:`batch_rollout` batches."""


def batch_rollout(
    spec: LoopSpec,
    inputs: LoopInputs,
    constants: LoopConstants,
    axes: LoopInputs,
    constant_axes: LoopConstants | None = None,
) -> TickLog:
    """Many runs at once: ``jax.vmap`` over the leaves of ``inputs`` whose entry in ``axes`` is 0
    (None: shared), and over those of ``constants`` marked 0 in ``constant_axes`` (default: all
    shared; e.g. a model and setpoints per run).

    The batch axis is split over every JAX device (``jax.sharding``: one shard per device, shared
    leaves replicated), so the same call uses all GPUs of a workstation, or the host devices XLA is
    told to make. A batch that does not divide among the devices is padded with copies of its last
    run, which are dropped from the result."""
    constant_axes = constant_axes or LoopConstants(None, None, None)

    def sizes(axis: int | None, sub: object) -> set[int]:
        return (
            {np.shape(leaf)[0] for leaf in jax.tree_util.tree_leaves(sub)} if axis == 0 else set()
        )

    batch = set()
    for tree_axes, tree in ((axes, inputs), (constant_axes, constants)):
        batch |= set().union(
            *jax.tree_util.tree_leaves(
                jax.tree_util.tree_map(sizes, tree_axes, tree, is_leaf=_none)
            )
        )
    if len(batch) != 1:
        raise ValueError(f"the batched inputs must share one batch size, got {sorted(batch)}")
    n = batch.pop()
    devices = jax.devices()
    # a whole number of runs per device
    index = np.minimum(np.arange(n + (-n) % len(devices)), n - 1)
    mesh = Mesh(np.array(devices), ("batch",))
    split, shared = (
        NamedSharding(mesh, PartitionSpec("batch")),
        NamedSharding(mesh, PartitionSpec()),
    )

    def place(axis: int | None, sub: object) -> object:
        if axis is None:
            return jax.device_put(sub, shared)
        return jax.device_put(
            jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[index], sub), split
        )

    placed = jax.tree_util.tree_map(place, axes, inputs, is_leaf=_none)
    placed_constants = jax.tree_util.tree_map(place, constant_axes, constants, is_leaf=_none)
    logs = _batched(spec, axes, constant_axes)(placed, placed_constants)
    return logs if len(index) == n else jax.tree_util.tree_map(lambda a: a[:n], logs)


@functools.lru_cache(maxsize=16)
def _batched(spec: LoopSpec, axes: LoopInputs, constant_axes: LoopConstants):
    """The vmapped loop compiled once per spec and batch layout (a new jit per call would compile
    every batch)."""
    return jax.jit(
        jax.vmap(partial(rollout, spec), in_axes=(axes, constant_axes)),
        compiler_options=XLA_OPTIONS,
    )


def _none(a: object) -> bool:
    """Leaf test for in_axes trees: None marks a shared input."""
    return a is None


def metrics_window(spec: LoopSpec, log: TickLog) -> slice:
    """The ticks the metrics cover in one run's TickLog: from the first command, ``n_eval`` of
    them."""
    first = int(np.argmax(np.asarray(log.ran)))
    return slice(first, first + spec.n_eval)


def evaluate(spec: LoopSpec, log: TickLog, name: str = "") -> metrics.RunMetrics:
    """The experiment's metrics of one run's TickLog (over :func:`metrics_window`)."""
    window = metrics_window(spec, log)
    t = (
        np.arange(spec.n_eval) * spec.period_ms * MS
    ) * 1e-9  # as the experiment's log: whole ns, then seconds
    chiee, chiee_des = np.asarray(log.chiee)[window], np.asarray(log.chiee_des)[window]
    return metrics.evaluate_run(
        t[: len(chiee)],
        chiee_des[:, :2],
        chiee[:, :2],
        np.asarray(log.saturated)[window],
        duration=spec.n_eval * spec.period_ms * 1e-3,
        name=name,
    )


def noise_batch(disturbance, spec: LoopSpec, seeds: np.ndarray) -> np.ndarray:
    """The mocap noise of one run per seed, (len(seeds), n_samples, 3): each equal to :func:`noise`
    with that seed (the same generator, drawn in one call instead of sample by sample)."""
    n = spec.n_ticks * spec.period_ms // MOCAP_MS + 2
    std = np.asarray(disturbance.pose_noise_std, dtype=np.float64)
    return np.stack([np.random.default_rng(int(s)).normal(0.0, 1.0, (n, 3)) for s in seeds]) * std

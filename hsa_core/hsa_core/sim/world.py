"""The simulated world, defined once: plant with its declared mismatch, MX-28 servos, motion capture
(no ROS).

Both simulations take the hardware from here: the offline experiment
(:mod:`hsa_core.sim.experiment`) and the ROS simulator (``hsa_sim_node``, behind the emulated MX-28
bus). What it models, on a 1 ms grid (integer nanoseconds, so both paths hit the same instants
exactly):

* **Plant** — the JAX model with the plant/model mismatch of
  :class:`~hsa_core.sim.disturbance.DisturbanceModel`, integrated with RK4 (two 0.5 ms steps per
  grid interval), the rod twists held over each interval. It starts hanging at rest with φ = 0.
* **Servos** — one per motor, in ticks: a goal written at t takes effect at t +
  ``actuation_latency`` (bus transfer and the servo's own cycle); the shaft then moves towards it at
  no more than the MX-28's no-load speed (55 rev/min at 12 V, ROBOTIS e-Manual MX-28(2.0)
  specifications), and stops on it. Evidence for a pure speed cap, without an extra first-order lag:
  the executed twists of the paper's GBN records are ramp-like at that speed (spec identification.md
  §2.2); the MX-28's position loop (Position P gain 850, D and I 0 by default) is not otherwise
  characterised in the records. The plant sees the continuous shaft angle; Present Position reports
  it rounded to whole ticks. Torque off freezes the shaft where it is. A run whose goals went
  through the September driver's queue (``DisturbanceModel.command_queue_depth``) has each motor's
  goal written when that driver got to it (:mod:`hsa_core.sim.command_queue`), then the latency.
* **Motion capture** — a sample every 5 ms (200 Hz), stamped with the instant the plant was at that
  pose, carrying the declared white noise, available ``measurement_latency`` after its stamp. Noise
  comes from one seeded generator, drawn sample by sample, so a seed fixes the whole run.
* **Payload** — the point mass m_pl at the parameters' CoG_pl (model.md), as in the identification
  campaign's staircases (docs/identification.md): :meth:`World.set_payload` changes it at an exact
  grid instant, the motors holding whatever they hold. It is the plant's m_pl until the first change
  (the parameter sets' 0 kg).

Events are integer nanoseconds; a time that is not on the grid is rounded up to the next grid point.

**One world interval.** What happens in one grid interval is one pure, JAX-traceable function of the
world's parameters (:class:`WorldParams`: plant, servo speed cap, wiring) and state:
:func:`interval_fn`; the plant's start (:func:`hanging_at_rest`) and a mocap sample
(:func:`mocap_sample`) are functions too. :class:`World` runs them on its event grid, and the
batched closed loop (:mod:`hsa_core.sim.closed_loop`) inside its ``lax.scan``: a parameter that
reaches one path reaches the other.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from numpy.typing import ArrayLike

from hsa_core import resultcache
from hsa_core.model import kinematics, simulation
from hsa_core.model.actuation import RAD_PER_TICK, TICKS_PER_RAD, MotorMap
from hsa_core.model.params import HsaParams
from hsa_core.sim import command_queue
from hsa_core.sim.disturbance import DisturbanceModel

GRID_NS = 1_000_000
"""[ns] the world's event grid: 1 ms."""
MOCAP_PERIOD_NS = 5 * GRID_NS
"""[ns] motion-capture period: 200 Hz."""
PLANT_SUBSTEPS = 2
"""RK4 steps per grid interval (0.5 ms each)."""


def to_grid(t_ns: int) -> int:
    """The first grid instant at or after ``t_ns``."""
    return -(-int(t_ns) // GRID_NS) * GRID_NS


def seconds_to_ns(t: float) -> int:
    """Seconds → integer nanoseconds (rounded), the world's time unit."""
    return int(round(t * 1e9))


def payload_schedule(flat: Sequence[float]) -> tuple[tuple[int, float], ...]:
    """Flat pairs [t0, m0, t1, m1, ...] (from t_k [s] the payload is m_k [kg]) → ((t_k [ns], m_k),
    ...).

    Raises ValueError with a one-line reason unless the length is even, the times finite, >= 0 and
    increasing and the masses finite and >= 0."""
    values = [float(v) for v in flat]
    if len(values) % 2:
        raise ValueError(f"needs pairs [t0, m0, t1, m1, ...], got {len(values)} values")
    times, masses = values[0::2], values[1::2]
    if not all(math.isfinite(v) for v in values):
        raise ValueError("times and masses must be finite")
    if any(t < 0.0 for t in times) or any(b <= a for a, b in zip(times, times[1:])):
        raise ValueError(f"times must be >= 0 s and increasing, got {times}")
    if any(m < 0.0 for m in masses):
        raise ValueError(f"masses must be >= 0 kg, got {masses}")
    return tuple((seconds_to_ns(t), m) for t, m in zip(times, masses))


class WorldParams(NamedTuple):
    """What one grid interval depends on (a pytree: traced, batchable with ``jax.vmap``)."""

    plant: HsaParams  # the simulated plant (with its payload m_pl)
    servo_speed: ArrayLike  # [ticks per grid interval] the servos' speed cap
    neutral: ArrayLike  # (motors,) [ticks] the motors' neutral positions
    to_rods: ArrayLike  # (rods, motors) [rad per tick] shaft ticks → virtual-rod twists
    servo_lag: ArrayLike = 0.0  # [s] the servos' position loop's time constant (0: none)


def world_params(
    plant: HsaParams, motor_map: MotorMap, speed: ArrayLike, lag: ArrayLike = 0.0
) -> WorldParams:
    """The world's parameters from the plant, the robot's wiring, the servos' speed cap [ticks per
    grid interval, :func:`servo_speed`] and their position loop's time constant [s] (0: the shaft
    slews at the cap to the goal)."""
    return WorldParams(
        plant,
        speed,
        jnp.asarray(motor_map.neutral_ticks, dtype=jnp.float64),
        jnp.asarray(motor_map.rod_twists(np.eye(len(motor_map.ids)))) * RAD_PER_TICK,
        lag,
    )


def servo_speed(max_speed: ArrayLike) -> ArrayLike:
    """A shaft speed [rad/s] as the most ticks it moves in one grid interval."""
    return max_speed * TICKS_PER_RAD * GRID_NS * 1e-9


def interval_fn(
    params: WorldParams,
) -> Callable[[Array, Array, Array, ArrayLike], tuple[Array, Array]]:
    """One grid interval of the world, pure and traceable (the plant's parameter terms are computed
    here, once).

    The returned ``interval(x, position, goal, torque) → (x, position)`` takes the plant state [q,
    q_dot], the shaft positions and the goal in force [ticks] and whether each motor has torque: the
    shafts with torque move towards the goal by the first-order step of the position loop (the whole
    way when ``servo_lag`` is 0) but at most the speed cap, then the plant is integrated over the
    interval with ``PLANT_SUBSTEPS`` RK4 steps, the twists those shafts realise held."""
    q_ddot = simulation.forward_dynamics_fn(params.plant)
    dt = GRID_NS * 1e-9 / PLANT_SUBSTEPS
    speed = params.servo_speed
    lag = jnp.asarray(params.servo_lag, dtype=jnp.float64)
    gain = 1.0 - jnp.exp(-GRID_NS * 1e-9 / lag)  # exactly 1 for lag 0

    def interval(x: Array, position: Array, goal: Array, torque: ArrayLike) -> tuple[Array, Array]:
        step = jnp.clip((goal - position) * gain, -speed, speed)
        moved = jnp.where(torque, position + step, position)
        phi = params.to_rods @ (moved - params.neutral)
        # no loop per interval: ~5 % of the batched loop's instant
        x = jax.lax.fori_loop(
            0, PLANT_SUBSTEPS, lambda _, xk: simulation.rk4(q_ddot, xk, phi, dt), x, unroll=True
        )
        return x, moved

    return interval


def hanging_at_rest(plant: HsaParams) -> Array:
    """The plant's state at the world's start: hanging at rest with φ = 0 (5 s settled, velocities
    exactly 0)."""
    return simulation.steady_state_rollout(plant, jnp.zeros(2)).at[3:].set(0.0)


def mocap_sample(plant: HsaParams, x: Array, noise: ArrayLike) -> Array:
    """A motion-capture sample of the plant in state x: its planar end-effector pose (x, y, θ) plus
    the noise draw."""
    return kinematics.end_effector_pose(plant, x[:3]) + noise


@dataclass(frozen=True)
class MocapSample:
    """One motion-capture sample: stamp [ns], the instant it becomes available [ns], noisy planar
    pose (x, y, θ)."""

    stamp_ns: int
    available_ns: int
    chiee: np.ndarray


class World:
    """Plant + servos + motion capture on the 1 ms grid; state in, events in, samples out (see the
    module docstring).

    ``advance_to(t)`` runs the grid up to t; ``write_goals`` / ``set_torque`` are what a bus client
    does at the current instant; ``set_payload`` is the experimenter's hand; ``take_samples(t)``
    hands over the mocap samples available by t, in stamp order. ``plant`` is the plant in force now
    (its m_pl the payload of the current instant).
    """

    def __init__(
        self, model: HsaParams, disturbance: DisturbanceModel, motor_map: MotorMap
    ) -> None:
        self.disturbance = disturbance
        self.plant = disturbance.plant_params(model)
        self.motor_map = motor_map
        self._neutral = np.asarray(motor_map.neutral_ticks, dtype=np.float64)
        self.params = world_params(
            self.plant,
            motor_map,
            servo_speed(disturbance.servo_max_speed),
            disturbance.servo_time_constant,
        )
        self._segment = _segment_fn(self.params)
        self._observe = jax.jit(functools.partial(mocap_sample, self.plant))
        self._rng = disturbance.rng()
        x = np.array(
            resultcache.cached(
                "hanging_at_rest",
                (self.plant,),
                lambda: {  # kept from a last start
                    "x": hanging_at_rest(self.plant)
                },
            )["x"]
        )
        x[3:] = 0.0  # also in a state cached before hanging_at_rest zeroed the velocities
        self.x = jnp.asarray(x)
        self.position = self._neutral.copy()  # shaft positions [ticks], continuous
        self.velocity = np.zeros_like(self.position)  # [ticks/s], over the last grid interval
        self.goal = self._neutral.copy()  # goal in force [ticks]
        self.torque = np.ones(len(self._neutral), dtype=bool)
        self.t_ns = 0
        self._latency_ns = seconds_to_ns(disturbance.actuation_latency)
        self._sample_latency_ns = seconds_to_ns(disturbance.measurement_latency)
        self._goals: deque[tuple[int, np.ndarray]] = deque()  # (effective at [ns], goal ticks)
        self._queue = (
            command_queue.initial(self.goal, disturbance.command_queue_depth)
            if disturbance.command_queue_depth
            else None
        )
        self._payloads: list[
            tuple[int, int, float]
        ] = []  # (effective at [ns], order set, mass [kg]), sorted
        self._payload_seq = 0
        self._samples: deque[MocapSample] = deque()
        self._sample()

    # ---------------------------------------------------------------- inputs (what the bus client
    # does)
    def write_goals(self, ticks: ArrayLike, at_ns: int | None = None) -> None:
        """Goal Position of every motor written at ``at_ns`` (default: now); it takes effect after
        the latency. With a command queue (``DisturbanceModel.command_queue_depth``) this is a tick
        publishing them: the driver writes them when it gets to them
        (:mod:`hsa_core.sim.command_queue`)."""
        at = self.t_ns if at_ns is None else int(at_ns)
        goal = np.asarray(ticks, dtype=np.float64).copy()
        if self._queue is None:
            self._goals.append((to_grid(at + self._latency_ns), goal))
            return
        at_ms = to_grid(at) // GRID_NS
        self._serve(at_ms)
        self._queue = command_queue.publish(self._queue, goal, at_ms)

    def _serve(self, until_ms: int) -> None:
        """The command queue's cycles that start before ``until_ms``: their writes take effect
        after the latency."""
        while command_queue.has_work(self._queue) and self._queue.cursor < until_ms:
            self._queue, done = command_queue.cycle(
                self._queue, self.disturbance.command_transaction_ms
            )
            for m in np.flatnonzero(done.wrote):
                at = int(done.at[m]) * GRID_NS
                self._goals.append((to_grid(at + self._latency_ns), done.vectors[m].copy()))

    def set_torque(self, on: ArrayLike) -> None:
        """Torque Enable of every motor, from now on (off: the shaft stays where it is)."""
        self.torque = np.asarray(on, dtype=bool).copy()

    def set_payload(self, mass_kg: float, at_ns: int | None = None) -> None:
        """From grid instant ``at_ns`` on (default: now; rounded up to the grid) the payload is
        ``mass_kg`` [kg].

        Events may be set ahead in any order; of two at the same instant the later set wins. The
        mass is a traced input of the jitted plant, so changing it does not recompile."""
        if not (math.isfinite(mass_kg) and mass_kg >= 0.0):
            raise ValueError(f"payload mass must be finite and >= 0 kg, got {mass_kg}")
        at = to_grid(self.t_ns if at_ns is None else at_ns)
        bisect.insort(self._payloads, (at, self._payload_seq, float(mass_kg)))
        self._payload_seq += 1

    # ---------------------------------------------------------------- time
    def advance_to(self, t_ns: int) -> None:
        """Run the grid up to ``t_ns`` (rounded up to the grid); the state is then that of instant
        t.

        Per grid interval: apply the goals and payload due, move the shafts, integrate the plant; on
        reaching an instant on the 5 ms grid, sample the pose. Intervals without an event in between
        run as one jitted segment."""
        end = to_grid(t_ns)
        if self._queue is not None:
            self._serve(end // GRID_NS)
        while self.t_ns < end:
            t = self.t_ns
            while self._goals and self._goals[0][0] <= t:
                self.goal = self._goals.popleft()[1]
            while self._payloads and self._payloads[0][0] <= t:
                self.plant = self.plant.replace(m_pl=self._payloads.pop(0)[2])
            stop = min(end, (t // MOCAP_PERIOD_NS + 1) * MOCAP_PERIOD_NS)
            for events in (self._goals, self._payloads):
                if events:
                    stop = min(stop, max(events[0][0], t + GRID_NS))
            x, position, velocity = self._segment(
                self.x,
                self.position,
                self.goal,
                self.torque,
                self.plant.m_pl,
                (stop - t) // GRID_NS,
            )
            self.x = x
            self.position, self.velocity = np.array(position), np.array(velocity) / (GRID_NS * 1e-9)
            self.t_ns = stop
            self._sample()

    def _sample(self) -> None:
        """Take the mocap sample of the current instant if one is due (every 5 ms, from t = 0)."""
        t = self.t_ns
        if t % MOCAP_PERIOD_NS == 0:
            # + noise
            chiee = np.asarray(
                self._observe(self.x, self.disturbance.measure(self._rng, np.zeros(3)))
            )
            self._samples.append(MocapSample(t, t + self._sample_latency_ns, chiee))

    # ---------------------------------------------------------------- outputs
    def twists(self) -> np.ndarray:
        """Virtual-rod twists φ [rad] the shafts realise now (continuous angle, not the reported
        ticks)."""
        return self.motor_map.rod_twists((self.position - self._neutral) * RAD_PER_TICK)

    def present_ticks(self) -> np.ndarray:
        """Present Position of every motor [ticks], as the servo reports it (rounded to whole
        ticks)."""
        return np.rint(self.position).astype(np.int64)

    def true_pose(self) -> np.ndarray:
        """Noise-free planar end-effector pose (x, y, θ) of the plant now."""
        return np.asarray(self._observe(self.x, np.zeros(3)))

    def next_sample_ns(self) -> int:
        """When the next not yet handed-over mocap sample becomes available [ns]."""
        if self._samples:
            return self._samples[0].available_ns
        next_stamp = (
            self.t_ns // MOCAP_PERIOD_NS + 1
        ) * MOCAP_PERIOD_NS  # the current instant's is taken already
        return next_stamp + self._sample_latency_ns

    def take_samples(self, t_ns: int) -> list[MocapSample]:
        """The samples available by ``t_ns`` (the world must have been advanced past their stamps),
        oldest first."""
        out = []
        while self._samples and self._samples[0].available_ns <= t_ns:
            out.append(self._samples.popleft())
        return out


def _segment_fn(params: WorldParams):
    """Jitted run of n grid intervals (:func:`interval_fn`) with goal and payload held: (x, shaft
    ticks, goal, torque, m_pl, n) → (x, ticks, last step); the payload m_pl is a traced input (a new
    mass does not recompile)."""

    @jax.jit
    def segment(x, position, goal, torque, m_pl, n):
        interval = interval_fn(params._replace(plant=dataclasses.replace(params.plant, m_pl=m_pl)))

        def step(_, carry):
            x, position, _step = carry
            x, moved = interval(x, position, goal, torque)
            return x, moved, moved - position

        return jax.lax.fori_loop(0, n, step, (x, position, jnp.zeros_like(position)))

    return segment

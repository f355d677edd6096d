"""The simulated world, defined once: plant with its declared mismatch, MX-28 servos, motion capture (no ROS).

Both simulations take the hardware from here: the offline experiment (:mod:`hsa_core.experiment`) and the ROS
simulator (``hsa_sim_node``, behind the emulated MX-28 bus). What it models, on a 1 ms grid (integer nanoseconds, so
both paths hit the same instants exactly):

* **Plant** — the JAX model with the plant/model mismatch of :class:`~hsa_core.disturbance.DisturbanceModel`,
  integrated with RK4 (two 0.5 ms steps per grid interval), the rod twists held over each interval. It starts hanging
  at rest with φ = 0.
* **Servos** — one per motor, in ticks: a goal written at t takes effect at t + ``actuation_latency`` (bus transfer
  and the servo's own cycle); the shaft then moves towards it at no more than the MX-28's no-load speed (55 rev/min
  at 12 V, ROBOTIS e-Manual MX-28(2.0) specifications), and stops on it. Evidence for a pure speed cap, without an
  extra first-order lag: the executed twists of the paper's GBN records are ramp-like at that speed
  (spec identification.md §2.2); the MX-28's position loop (Position P gain 850, D and I 0 by default) is not
  otherwise characterised in the records. The plant sees the continuous shaft angle; Present Position reports it
  rounded to whole ticks. Torque off freezes the shaft where it is.
* **Motion capture** — a sample every 5 ms (200 Hz), stamped with the instant the plant was at that pose, carrying
  the declared white noise, available ``measurement_latency`` after its stamp. Noise comes from one seeded generator,
  drawn sample by sample, so a seed fixes the whole run.
* **Payload** — the point mass m_pl at the parameters' CoG_pl (model.md), as in the identification campaign's
  staircases (docs/identification.md): :meth:`World.set_payload` changes it at an exact grid instant, the motors
  holding whatever they hold. It is the plant's m_pl until the first change (the parameter sets' 0 kg).

Events are integer nanoseconds; a time that is not on the grid is rounded up to the next grid point.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from hsa_core import kinematics, resultcache, simulation
from hsa_core.actuation import RAD_PER_TICK, TICKS_PER_RAD, MotorMap
from hsa_core.disturbance import DisturbanceModel
from hsa_core.params import HsaParams

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
    """Flat pairs [t0, m0, t1, m1, ...] (from t_k [s] the payload is m_k [kg]) → ((t_k [ns], m_k), ...).

    Raises ValueError with a one-line reason unless the length is even, the times finite, >= 0 and increasing and
    the masses finite and >= 0."""
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


@dataclass(frozen=True)
class MocapSample:
    """One motion-capture sample: stamp [ns], the instant it becomes available [ns], noisy planar pose (x, y, θ)."""

    stamp_ns: int
    available_ns: int
    chiee: np.ndarray


class World:
    """Plant + servos + motion capture on the 1 ms grid; state in, events in, samples out (see the module docstring).

    ``advance_to(t)`` runs the grid up to t; ``write_goals`` / ``set_torque`` are what a bus client does at the current
    instant; ``set_payload`` is the experimenter's hand; ``take_samples(t)`` hands over the mocap samples available
    by t, in stamp order. ``plant`` is the plant in force now (its m_pl the payload of the current instant).
    """

    def __init__(self, model: HsaParams, disturbance: DisturbanceModel, motor_map: MotorMap) -> None:
        self.disturbance = disturbance
        self.plant = disturbance.plant_params(model)
        self.motor_map = motor_map
        self._neutral = np.asarray(motor_map.neutral_ticks, dtype=np.float64)
        speed = disturbance.servo_max_speed * TICKS_PER_RAD * GRID_NS * 1e-9  # ticks per grid interval
        self._segment = _segment_fn(self.plant, motor_map, self._neutral, speed)
        self._pose = _pose_fn(self.plant)
        self._rng = disturbance.rng()
        x = np.array(resultcache.cached("hanging_at_rest", (self.plant,), lambda: {  # kept from a last start
            "x": simulation.steady_state_rollout(self.plant, np.zeros(2))})["x"])
        x[3:] = 0.0
        self.x = jnp.asarray(x)
        self.position = self._neutral.copy()  # shaft positions [ticks], continuous
        self.velocity = np.zeros_like(self.position)  # [ticks/s], over the last grid interval
        self.goal = self._neutral.copy()  # goal in force [ticks]
        self.torque = np.ones(len(self._neutral), dtype=bool)
        self.t_ns = 0
        self._latency_ns = seconds_to_ns(disturbance.actuation_latency)
        self._sample_latency_ns = seconds_to_ns(disturbance.measurement_latency)
        self._goals: deque[tuple[int, np.ndarray]] = deque()  # (effective at [ns], goal ticks)
        self._payloads: list[tuple[int, int, float]] = []  # (effective at [ns], order set, mass [kg]), sorted
        self._payload_seq = 0
        self._samples: deque[MocapSample] = deque()
        self._sample()

    # ---------------------------------------------------------------- inputs (what the bus client does)
    def write_goals(self, ticks: ArrayLike, at_ns: int | None = None) -> None:
        """Goal Position of every motor written at ``at_ns`` (default: now); it takes effect after the latency."""
        at = self.t_ns if at_ns is None else int(at_ns)
        goal = np.asarray(ticks, dtype=np.float64).copy()
        self._goals.append((to_grid(at + self._latency_ns), goal))

    def set_torque(self, on: ArrayLike) -> None:
        """Torque Enable of every motor, from now on (off: the shaft stays where it is)."""
        self.torque = np.asarray(on, dtype=bool).copy()

    def set_payload(self, mass_kg: float, at_ns: int | None = None) -> None:
        """From grid instant ``at_ns`` on (default: now; rounded up to the grid) the payload is ``mass_kg`` [kg].

        Events may be set ahead in any order; of two at the same instant the later set wins. The mass is a traced
        input of the jitted plant, so changing it does not recompile."""
        if not (math.isfinite(mass_kg) and mass_kg >= 0.0):
            raise ValueError(f"payload mass must be finite and >= 0 kg, got {mass_kg}")
        at = to_grid(self.t_ns if at_ns is None else at_ns)
        bisect.insort(self._payloads, (at, self._payload_seq, float(mass_kg)))
        self._payload_seq += 1

    # ---------------------------------------------------------------- time
    def advance_to(self, t_ns: int) -> None:
        """Run the grid up to ``t_ns`` (rounded up to the grid); the state is then that of instant t.

        Per grid interval: apply the goals and payload due, move the shafts, integrate the plant; on reaching an
        instant on the 5 ms grid, sample the pose. Intervals without an event in between run as one jitted segment."""
        end = to_grid(t_ns)
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
            x, position, velocity = self._segment(self.x, self.position, self.goal, self.torque, self.plant.m_pl,
                                                  (stop - t) // GRID_NS)
            self.x = x
            self.position, self.velocity = np.array(position), np.array(velocity) / (GRID_NS * 1e-9)
            self.t_ns = stop
            self._sample()

    def _sample(self) -> None:
        """Take the mocap sample of the current instant if one is due (every 5 ms, from t = 0)."""
        t = self.t_ns
        if t % MOCAP_PERIOD_NS == 0:
            chiee = self.disturbance.measure(self._rng, self.true_pose())
            self._samples.append(MocapSample(t, t + self._sample_latency_ns, chiee))

    # ---------------------------------------------------------------- outputs
    def twists(self) -> np.ndarray:
        """Virtual-rod twists φ [rad] the shafts realise now (continuous angle, not the reported ticks)."""
        return self.motor_map.rod_twists((self.position - self._neutral) * RAD_PER_TICK)

    def present_ticks(self) -> np.ndarray:
        """Present Position of every motor [ticks], as the servo reports it (rounded to whole ticks)."""
        return np.rint(self.position).astype(np.int64)

    def true_pose(self) -> np.ndarray:
        """Noise-free planar end-effector pose (x, y, θ) of the plant now."""
        return np.asarray(self._pose(self.x))

    def next_sample_ns(self) -> int:
        """When the next not yet handed-over mocap sample becomes available [ns]."""
        if self._samples:
            return self._samples[0].available_ns
        next_stamp = (self.t_ns // MOCAP_PERIOD_NS + 1) * MOCAP_PERIOD_NS  # the current instant's is taken already
        return next_stamp + self._sample_latency_ns

    def take_samples(self, t_ns: int) -> list[MocapSample]:
        """The samples available by ``t_ns`` (the world must have been advanced past their stamps), oldest first."""
        out = []
        while self._samples and self._samples[0].available_ns <= t_ns:
            out.append(self._samples.popleft())
        return out


def _segment_fn(plant: HsaParams, motor_map: MotorMap, neutral: np.ndarray, speed: float):
    """Jitted run of n grid intervals with goal and payload held: (x, shaft ticks, goal, torque, m_pl, n) → (x, ticks,
    last step).

    Per interval the shafts move towards the goal by at most ``speed`` ticks (torque on), then the plant (with payload
    m_pl, a traced input: a new mass does not recompile) is integrated with the twists they realise held."""
    dt = GRID_NS * 1e-9 / PLANT_SUBSTEPS
    to_rods = jnp.asarray(motor_map.rod_twists(np.eye(len(neutral)))) * RAD_PER_TICK  # (rods, motors)
    neutral = jnp.asarray(neutral)

    @jax.jit
    def segment(x, position, goal, torque, m_pl, n):
        q_ddot = simulation.forward_dynamics_fn(dataclasses.replace(plant, m_pl=m_pl))  # parameter terms once

        def interval(_, carry):
            x, position, _step = carry
            moved = jnp.where(torque, position + jnp.clip(goal - position, -speed, speed), position)
            phi = to_rods @ (moved - neutral)
            x = jax.lax.fori_loop(0, PLANT_SUBSTEPS, lambda _, xk: simulation._rk4(q_ddot, xk, phi, dt), x)
            return x, moved, moved - position

        return jax.lax.fori_loop(0, n, interval, (x, position, jnp.zeros_like(position)))

    return segment


def _pose_fn(plant: HsaParams):
    """Jitted end-effector pose of the plant for its state x = [q, q_dot]."""
    return jax.jit(lambda x: kinematics.end_effector_pose(plant, x[:3]))

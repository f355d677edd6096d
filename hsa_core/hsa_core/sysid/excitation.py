"""Excitation sequences of the twist phi for identification and verification (identification.md
§2.2, §2.4).

Pure functions that return an :class:`Excitation`: a zero-order-hold sequence of phi = [phi1, phi2]
on a regular command grid (default 25 Hz, the rate of the original records). Sample k is commanded
over [t_k, t_k + dt).

* ``step``: phi = 0 until ``t_step``, then one level held to the end;
* ``staircase``: 0 and ``n_levels`` equal increments up to phi_max, each held ``hold`` s (5.8 s in
  the 2023 records);
* ``gbn``: generalized binary noise with a settling-time parameter (0.5 s as in the paper): at every
  command period the level is kept with probability 1 - dt / settling_time (mean hold =
  settling_time, minimum hold one period); at every switch a new level is drawn phi ~ U(0, phi_max).
  Seeded, so a realisation can be replayed on another robot.

The ``mode`` maps the scalar level sequence onto the two virtual rods: ``elongation`` (both rods the
same), ``rod1`` / ``rod2`` (bending: one rod twisted, the other at 0), ``combined`` (GBN only: both
rods independent).
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np
from numpy.typing import ArrayLike


class RodMode(enum.StrEnum):
    """How the level sequence drives the two rods (module docstring)."""

    ELONGATION = "elongation"
    ROD1 = "rod1"
    ROD2 = "rod2"
    COMBINED = "combined"  # GBN only


class ExcitationKind(enum.StrEnum):
    """The excitation family."""

    STEP = "step"
    STAIRCASE = "staircase"
    GBN = "gbn"


MODES = tuple(mode.value for mode in RodMode)
KINDS = tuple(kind.value for kind in ExcitationKind)
DEFAULT_DT = 0.04
"""Command period of the excitation [s] (25 Hz, identification.md §2.4)."""
DEFAULT_SETTLING_TIME = 0.5
"""GBN settling-time parameter of the paper's verification records [s]."""


@dataclasses.dataclass(frozen=True)
class Excitation:
    """A zero-order-hold phi sequence: sample k (phi[k], shape (2,)) is held over [t[k], t[k] +
    dt)."""

    t: np.ndarray
    phi: np.ndarray
    dt: float
    kind: ExcitationKind
    mode: RodMode
    seed: int | None = None

    @property
    def duration(self) -> float:
        """Length of the sequence [s] (end of the last hold)."""
        return float(len(self.t) * self.dt)

    def at(self, time: float) -> np.ndarray:
        """phi commanded at `time` s from the start (zero-order hold; the last sample after the end,
        0 before 0)."""
        if time < 0.0:
            return np.zeros(2)
        k = min(int(np.floor(time / self.dt + 1e-9)), len(self.t) - 1)
        return self.phi[k].copy()


def _check(
    phi_max: float, dt: float, mode: RodMode | str, allowed: tuple[str, ...] = MODES[:3]
) -> RodMode:
    """The mode as a RodMode; refuse non-positive limits and periods and unknown modes (ValueError
    naming the argument)."""
    if not (np.isfinite(phi_max) and phi_max > 0.0):
        raise ValueError(f"phi_max must be a finite angle > 0, got {phi_max!r}")
    if not (np.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be > 0, got {dt!r}")
    if mode not in allowed:
        raise ValueError(f"mode must be one of {list(allowed)}, got {mode!r}")
    return RodMode(mode)


def _to_rods(levels: np.ndarray, mode: RodMode) -> np.ndarray:
    """Map a scalar level sequence (N,) onto phi (N, 2) for elongation, rod1 or rod2."""
    zeros = np.zeros_like(levels)
    return {
        RodMode.ELONGATION: np.stack([levels, levels], axis=1),
        RodMode.ROD1: np.stack([levels, zeros], axis=1),
        RodMode.ROD2: np.stack([zeros, levels], axis=1),
    }[mode]


def _grid(duration: float, dt: float) -> np.ndarray:
    """Sample start times 0, dt, ... covering `duration`."""
    if not (np.isfinite(duration) and duration > 0.0):
        raise ValueError(f"duration must be > 0, got {duration!r}")
    return np.arange(int(np.ceil(duration / dt - 1e-9))) * dt


def step(
    phi_level: float,
    duration: float,
    t_step: float = 1.0,
    mode: RodMode | str = RodMode.ELONGATION,
    dt: float = DEFAULT_DT,
) -> Excitation:
    """Step from phi = 0 to `phi_level` at `t_step`, held until `duration` (identification.md §2.2,
    steps)."""
    mode = _check(phi_level, dt, mode)
    t = _grid(duration, dt)
    levels = np.where(t >= t_step - 1e-9, phi_level, 0.0)
    return Excitation(t, _to_rods(levels, mode), dt, ExcitationKind.STEP, mode)


def staircase(
    phi_max: float,
    n_levels: int = 5,
    hold: float = 5.8,
    mode: RodMode | str = RodMode.ELONGATION,
    dt: float = DEFAULT_DT,
) -> Excitation:
    """Levels 0, phi_max/n, ..., phi_max, each held `hold` s: (n_levels + 1) * hold s in all (§2.2,
    staircases)."""
    mode = _check(phi_max, dt, mode)
    if n_levels < 1:
        raise ValueError(f"n_levels must be >= 1, got {n_levels!r}")
    t = _grid((n_levels + 1) * hold, dt)
    index = np.minimum(np.floor(t / hold + 1e-9).astype(int), n_levels)
    phi = _to_rods(phi_max * index / n_levels, mode)
    return Excitation(t, phi, dt, ExcitationKind.STAIRCASE, mode)


def gbn(
    phi_max: float,
    duration: float,
    seed: int,
    settling_time: float = DEFAULT_SETTLING_TIME,
    mode: RodMode | str = RodMode.COMBINED,
    dt: float = DEFAULT_DT,
) -> Excitation:
    """Generalized binary noise with uniform levels U(0, phi_max), seeded (identification.md §2.4;
    see module doc)."""
    mode = _check(phi_max, dt, mode, MODES)
    if not settling_time >= dt:
        raise ValueError(f"settling_time must be >= dt = {dt}, got {settling_time!r}")
    t = _grid(duration, dt)
    rng = np.random.default_rng(seed)
    n_rods = 2 if mode is RodMode.COMBINED else 1
    switch = rng.random((len(t), n_rods)) < dt / settling_time
    switch[0] = True
    draws = rng.uniform(0.0, phi_max, (len(t), n_rods))
    # each row holds the draw of the most recent switch at or before it
    last = np.maximum.accumulate(np.where(switch, np.arange(len(t))[:, None], 0), axis=0)
    levels = np.take_along_axis(draws, last, axis=0)
    phi = levels if mode is RodMode.COMBINED else _to_rods(levels[:, 0], mode)
    return Excitation(t, phi, dt, ExcitationKind.GBN, mode, seed)


def make(
    kind: ExcitationKind | str,
    phi_max: float,
    *,
    duration: float = 50.0,
    mode: RodMode | str = RodMode.ELONGATION,
    seed: int = 0,
    level: float | None = None,
    n_levels: int = 5,
    hold: float = 5.8,
    t_step: float = 1.0,
    settling_time: float = DEFAULT_SETTLING_TIME,
    dt: float = DEFAULT_DT,
) -> Excitation:
    """Build an excitation by kind (or its name) with the arguments that kind uses (nodes, CLIs)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
    kind = ExcitationKind(kind)
    if kind is ExcitationKind.STEP:
        return step(phi_max if level is None else level, duration, t_step, mode, dt)
    if kind is ExcitationKind.STAIRCASE:
        return staircase(phi_max, n_levels, hold, mode, dt)
    return gbn(phi_max, duration, seed, settling_time, mode, dt)


def zero_order_hold(t_samples: ArrayLike, phi_samples: ArrayLike, t_query: ArrayLike) -> np.ndarray:
    """The newest phi sample at or before each query time (the first sample before it): resampling
    of motor reads."""
    t_samples, phi_samples = (
        np.asarray(t_samples, dtype=float),
        np.asarray(phi_samples, dtype=float),
    )
    index = np.clip(
        np.searchsorted(t_samples, np.asarray(t_query, dtype=float), side="right") - 1, 0, None
    )
    return phi_samples[index]

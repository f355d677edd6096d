"""Tracking metrics of experiments.md §4, computed from per-controller-tick logs.

Inputs are one row per controller tick k: the tick time t_k, the active setpoint p^d(t_k) and the
measured (mocap) EE position p_ee(t_k) used in that tick, both [x, y] in m, and optionally a
per-tick saturation flag. Definitions (e_k = ‖p^d(t_k) − p_ee(t_k)‖₂):

* **Time base and trimming.** t = 0 at the first tick (the first controller output). With
  ``duration`` (110 s for the step runs) only ticks with 0 ≤ t < duration are used. Nothing is
  resampled.
* **RMSE** = sqrt(mean_k e_k²) over the used ticks [m; the tables print mm].
* **Steps.** A step starts at tick 0 and at every tick whose setpoint differs from the previous
  tick's; it ends where the next step starts, the last one at ``duration`` (or, untrimmed, one
  median tick period after the last tick). e₀ = e at the step's first tick (the value at the
  change).
* **Response time** t_r = t of the first tick of the step with e < 0.1·e₀, minus the step's start
  time; NaN if it never happens within the step (counted as "not reached"); 0 if e₀ = 0.
* **Settling time** t_s = time from the step start until e stays ≤ max(0.1·e₀, 1 mm) for the rest of
  the step: the time of the tick after the last tick outside that band; 0 if no tick is outside; NaN
  if the last tick is outside.
* **Overshoot.** With the step direction d = (p^d − p_prev)/‖p^d − p_prev‖ (p_prev = the previous
  setpoint, or the measured p_ee at t = 0 for the first step), overshoot = max(0, max_k (p_ee,k −
  p^d)·d) over the step's ticks: how far the EE went past the target along the direction of the step
  [m], and as a percentage of the step size ‖p^d − p_prev‖. Errors across the step direction do not
  count. NaN for a zero-size step.
* **Steady-state error** = mean e over the step's ticks in its last 2 s [t_end − 2 s, t_end) (the
  whole step if it is shorter).
* **Saturated fraction** = fraction of used ticks flagged saturated; ``saturation_mask`` flags a
  tick when any commanded φ_i is at or beyond 0 or φ_max (within 1e-9 rad), which works for clipped
  and unclipped commands.
* **Effective control rate** = (number of used ticks − 1) / (t_last − t_first) [Hz].
* **Run summary.** Response time, settling time, overshoot and steady-state error are averaged over
  the steps after the first (the 10 steps after the first for the 11-step lists), ignoring NaN; the
  number of steps whose t_r was not reached is reported next to the mean.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

RESPONSE_FRACTION = 0.1
SETTLING_FLOOR = 1e-3  # m
STEADY_STATE_WINDOW = 2.0  # s


@dataclass(frozen=True)
class StepMetrics:
    """Metrics of one setpoint step (SI units: s, m; overshoot also in % of the step size)."""

    index: int
    t_start: float
    t_end: float
    p_des: tuple[float, float]
    step_size: float
    initial_error: float
    response_time: float
    settling_time: float
    overshoot: float
    overshoot_percent: float
    steady_state_error: float


@dataclass(frozen=True)
class RunMetrics:
    """Metrics of one run: RMSE, tick count and time span [s], rate, saturation, per-step metrics
    and their means."""

    name: str
    rmse: float
    n_ticks: int
    span: float
    control_rate: float
    saturated_fraction: float
    steps: tuple[StepMetrics, ...]
    response_time_mean: float
    n_not_reached: int
    settling_time_mean: float
    overshoot_mean: float
    overshoot_percent_mean: float
    steady_state_error_mean: float


def tracking_rmse(p_des: ArrayLike, p_ee: ArrayLike) -> float:
    """sqrt(mean_k ‖p^d_k − p_ee,k‖²) over the given ticks [m]."""
    err = np.asarray(p_des, dtype=np.float64) - np.asarray(p_ee, dtype=np.float64)
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def saturation_mask(phi: ArrayLike, phi_max: float | ArrayLike, atol: float = 1e-9) -> np.ndarray:
    """Per-tick flag: any commanded φ_i ≤ atol or ≥ φ_max − atol (at or beyond a saturation
    bound)."""
    phi = np.asarray(phi, dtype=np.float64)
    return np.any((phi <= atol) | (phi >= np.asarray(phi_max) - atol), axis=1)


def control_rate(t: ArrayLike) -> float:
    """Effective rate (N − 1)/(t_N − t_1) [Hz] of tick times t."""
    t = np.asarray(t, dtype=np.float64)
    return (t.size - 1) / float(t[-1] - t[0]) if t.size > 1 else math.nan


def step_bounds(p_des: ArrayLike) -> list[tuple[int, int]]:
    """Half-open tick index ranges [start, stop) of the steps: a step starts wherever the setpoint
    changes."""
    p_des = np.asarray(p_des, dtype=np.float64)
    changes = np.flatnonzero(np.any(p_des[1:] != p_des[:-1], axis=1)) + 1
    edges = [0, *changes.tolist(), p_des.shape[0]]
    return list(zip(edges[:-1], edges[1:]))


def step_metrics(
    index: int, t: np.ndarray, p_des: np.ndarray, p_ee: np.ndarray, p_prev: np.ndarray, t_end: float
) -> StepMetrics:
    """Metrics of one step from its ticks (t relative to the run start), the previous target and the
    step end time."""
    target = p_des[0]
    err = np.linalg.norm(p_des - p_ee, axis=1)
    e0 = float(err[0])
    t0 = float(t[0])
    if e0 == 0.0:
        response_time = 0.0
    else:
        below = np.flatnonzero(err < RESPONSE_FRACTION * e0)
        response_time = float(t[below[0]] - t0) if below.size else math.nan
    outside = np.flatnonzero(err > max(RESPONSE_FRACTION * e0, SETTLING_FLOOR))
    if not outside.size:
        settling_time = 0.0
    elif outside[-1] == err.size - 1:
        settling_time = math.nan
    else:
        settling_time = float(t[outside[-1] + 1] - t0)
    step = target - p_prev
    step_size = float(np.linalg.norm(step))
    if step_size > 0.0:
        overshoot = max(0.0, float(np.max((p_ee - target) @ (step / step_size))))
        overshoot_percent = 100.0 * overshoot / step_size
    else:
        overshoot = overshoot_percent = math.nan
    late = t >= t_end - STEADY_STATE_WINDOW
    steady_state_error = float(np.mean(err[late] if late.any() else err))
    return StepMetrics(
        index,
        t0,
        t_end,
        (float(target[0]), float(target[1])),
        step_size,
        e0,
        response_time,
        settling_time,
        overshoot,
        overshoot_percent,
        steady_state_error,
    )


def _nanmean(values: Sequence[float]) -> float:
    """Mean ignoring NaN; NaN if nothing is left."""
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


def evaluate_run(
    t: ArrayLike,
    p_des: ArrayLike,
    p_ee: ArrayLike,
    saturated: ArrayLike | None = None,
    duration: float | None = None,
    name: str = "",
) -> RunMetrics:
    """All metrics of one run from per-tick logs (definitions: module docstring); ``duration``
    trims, e.g. 110 s."""
    t = np.asarray(t, dtype=np.float64)
    p_des = np.asarray(p_des, dtype=np.float64)
    p_ee = np.asarray(p_ee, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or p_des.shape != (t.size, 2) or p_ee.shape != (t.size, 2):
        shapes = f"{t.shape}, {p_des.shape}, {p_ee.shape}"
        raise ValueError(f"need t (N,), p_des (N, 2), p_ee (N, 2) with N >= 2; got {shapes}")
    if np.any(np.diff(t) <= 0.0) or not (np.all(np.isfinite(p_des)) and np.all(np.isfinite(p_ee))):
        raise ValueError("tick times must increase strictly and positions must be finite")
    if duration is not None and not duration > 0.0:
        raise ValueError(f"duration must be > 0, got {duration}")
    t = t - t[0]
    keep = t < duration if duration is not None else np.ones(t.size, dtype=bool)
    t, p_des, p_ee = t[keep], p_des[keep], p_ee[keep]
    sat_fraction = math.nan
    if saturated is not None:
        sat = np.asarray(saturated, dtype=bool)
        if sat.shape != keep.shape:
            raise ValueError(f"saturated must have one flag per tick, got {sat.shape}")
        sat_fraction = float(np.mean(sat[keep]))
    run_end = duration if duration is not None else float(t[-1] + np.median(np.diff(t)))
    bounds = step_bounds(p_des)
    steps = tuple(
        step_metrics(
            i,
            t[a:b],
            p_des[a:b],
            p_ee[a:b],
            p_des[a - 1] if a > 0 else p_ee[0],
            float(t[b]) if b < t.size else run_end,
        )
        for i, (a, b) in enumerate(bounds)
    )
    later = steps[1:]
    return RunMetrics(
        name=name,
        rmse=tracking_rmse(p_des, p_ee),
        n_ticks=int(t.size),
        span=float(t[-1]),
        control_rate=control_rate(t),
        saturated_fraction=sat_fraction,
        steps=steps,
        response_time_mean=_nanmean([s.response_time for s in later]),
        n_not_reached=sum(math.isnan(s.response_time) for s in later),
        settling_time_mean=_nanmean([s.settling_time for s in later]),
        overshoot_mean=_nanmean([s.overshoot for s in later]),
        overshoot_percent_mean=_nanmean([s.overshoot_percent for s in later]),
        steady_state_error_mean=_nanmean([s.steady_state_error for s in later]),
    )


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Plain-text table with right-aligned columns."""
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)
    ]
    lines = [
        "  ".join(h.rjust(w) for h, w in zip(header, widths)),
        "  ".join("-" * w for w in widths),
    ]
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)


def _fmt(value: float, scale: float = 1.0, digits: int = 2) -> str:
    """Number scaled and rounded, or '–' for NaN."""
    return "–" if math.isnan(value) else f"{value * scale:.{digits}f}"


def format_summary(runs: Sequence[RunMetrics]) -> str:
    """Summary table, one row per run: RMSE, mean t_r (not reached), t_s, overshoot, e_ss [mm],
    saturation, rate."""
    header = [
        "run",
        "RMSE [mm]",
        "t_r [s]",
        "t_s [s]",
        "overshoot [mm]",
        "overshoot [%]",
        "e_ss [mm]",
        "saturated [%]",
        "rate [Hz]",
        "ticks",
    ]
    rows = [
        [
            r.name,
            _fmt(r.rmse, 1e3),
            _fmt(r.response_time_mean) + (f" ({r.n_not_reached} n.r.)" if r.n_not_reached else ""),
            _fmt(r.settling_time_mean),
            _fmt(r.overshoot_mean, 1e3),
            _fmt(r.overshoot_percent_mean, 1.0, 1),
            _fmt(r.steady_state_error_mean, 1e3),
            _fmt(r.saturated_fraction, 100.0, 1),
            _fmt(r.control_rate, 1.0, 1),
            str(r.n_ticks),
        ]
        for r in runs
    ]
    return _table(header, rows)


def format_steps(run: RunMetrics) -> str:
    """Per-step table of one run (positions and errors in mm, times in s)."""
    header = [
        "step",
        "t [s]",
        "x^d [mm]",
        "y^d [mm]",
        "size [mm]",
        "e0 [mm]",
        "t_r [s]",
        "t_s [s]",
        "overshoot [mm]",
        "overshoot [%]",
        "e_ss [mm]",
    ]
    rows = [
        [
            str(s.index + 1),
            _fmt(s.t_start),
            _fmt(s.p_des[0], 1e3),
            _fmt(s.p_des[1], 1e3),
            _fmt(s.step_size, 1e3),
            _fmt(s.initial_error, 1e3),
            _fmt(s.response_time),
            _fmt(s.settling_time),
            _fmt(s.overshoot, 1e3),
            _fmt(s.overshoot_percent, 1.0, 1),
            _fmt(s.steady_state_error, 1e3),
        ]
        for s in run.steps
    ]
    return _table(header, rows)

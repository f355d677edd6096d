"""How far a run (simulated or real) is from a reference run of the real robot, step by step (no
ROS).

A run is its measured end-effector position and the setpoint in force, sampled at increasing times
(:class:`StepRun`; a simulation's controller ticks, or a reference run's 100 Hz grid). Its steps
start where the setpoint moves (:func:`hsa_core.runs.reference.step_instants`); step k ends
where step k + 1 starts, the last one at the run's ``end``. The measures (positions in m, times in
s):

* **D** (:func:`deviation`) = RMS over steps 1–10 and over the first 9.3 s after each step's own
  instant (each run aligned at its own step instant), on a 10 ms grid (positions interpolated
  linearly), of ‖p_run − p_ref‖;
* **end peak-to-peak** (:func:`end_peak_to_peak`): per step and axis, max − min of the samples in
  the step's last 2 s;
* **end error** (:func:`end_error`): per step, mean ‖p^d − p‖ over the samples in its last 2 s;
* **response time** (:func:`response_times`): per step, on the aligned 10 ms grid, the first time
  ‖p^d − p‖ falls below 10 % of its value at the step instant (experiments.md §4), NaN if it never
  does within the window;
* **rise time** (:func:`rise_times`): per step, on the aligned grid, the time the progress along the
  step, s = (p − p₀)·(p^d − p₀)/‖p^d − p₀‖² (p₀ = p at the step instant), takes from first reaching
  10 % to first reaching 90 %, NaN if it never does;
* **overshoot** (:func:`overshoots`): per step, on the aligned grid, how far p went past the
  setpoint along the step's direction d = (p^d_k − p^d_{k−1})/‖p^d_k − p^d_{k−1}‖, max(0, max_j (p_j
  − p^d_k)·d) (as hsa_core.analysis.metrics), NaN for a zero-size step;
* **D per step** (:func:`step_deviations`): D of each step alone;
* :func:`step_table` puts every per-step measure of a run and a reference side by side
  (``hsa_analyze --against``);
* **onset time** (:func:`onset_times`): per step, the aligned time the progress first reaches 10 %;
* **systematic and random parts** (:func:`split_realizations`): over several realizations of one
  run (noise seeds), RMS over them of D² = D(their mean response)² + RMS of their distance from
  that mean², exactly (each part over any window of the aligned responses);
* **contour deviation** (:func:`contour_deviation`): for a run without steps (a contour), the run
  is aligned with the reference at the time shift that brings their setpoints closest (RMS over
  the reference's samples), and D is the RMS of ‖p_run − p_ref‖ over the reference's samples that
  the shifted run covers, on the reference's own sample times; and how far the reference trails
  the run along the contour (the further time shift of the run's p, within ± 0.5 s, that brings it
  closest to the reference's p; negative: the reference leads) with D at that lag;
* :func:`compare` collects them as the sim-versus-real table: D, x peak-to-peak (max
  over steps), end error (median over steps), the median relative rise- and response-time
  differences and each run's RMSE.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hsa_core.analysis.metrics import RESPONSE_FRACTION, STEADY_STATE_WINDOW
from hsa_core.runs.reference import step_instants

STEPS = tuple(range(1, 11))
"""Steps compared (step 0 is the start from rest)."""
HORIZON = 9.3
"""[s] the part of each step compared by D: the shortest real step is 9.5 s."""
GRID = 0.01
"""[s] the grid of the aligned responses (the resolution of the reference data)."""


@dataclass(frozen=True)
class StepRun:
    """A run: sample times t (n,) [s], measured position p (n, 2) [m], setpoint in force p_des (n,
    2) [m], end [s]."""

    t: np.ndarray
    p: np.ndarray
    p_des: np.ndarray
    end: float

    def __post_init__(self) -> None:
        """Reject shapes that do not match and times that do not increase."""
        n = len(self.t)
        if np.shape(self.p) != (n, 2) or np.shape(self.p_des) != (n, 2):
            raise ValueError(
                f"p and p_des must be ({n}, 2), got {np.shape(self.p)} and {np.shape(self.p_des)}"
            )
        if n < 2 or np.any(np.diff(self.t) <= 0.0):
            raise ValueError("t must hold at least two increasing sample times")

    @classmethod
    def of_log(cls, log: Any, end: float) -> StepRun:
        """The run of a tick log (``t``, ``chiee``, ``chiee_des``: the offline experiment's or a
        bag's): its measured planar position and setpoint."""
        return cls(log.t, log.chiee[:, :2], log.chiee_des[:, :2], end)

    @property
    def step_starts(self) -> np.ndarray:
        """[s] the instants of steps 1, 2, ... (where the setpoint moves)."""
        return step_instants(self.t, self.p_des)

    def step_bounds(self, steps: tuple[int, ...] = STEPS) -> list[tuple[float, float]]:
        """[(start, end)] [s] of each of ``steps``; ValueError (one line) if the run does not have
        them."""
        starts = self.step_starts
        if len(starts) < max(steps):
            raise ValueError(f"the run has {len(starts) + 1} steps, {max(steps) + 1} are compared")
        ends = np.append(starts[1:], self.end)
        return [(float(starts[k - 1]), float(ends[k - 1])) for k in steps]

    def setpoint_at(self, t: float) -> np.ndarray:
        """The setpoint in force at t (the last sample at or before t)."""
        return self.p_des[max(int(np.searchsorted(self.t, t, side="right")) - 1, 0)]


def aligned_responses(
    run: StepRun, steps: tuple[int, ...] = STEPS, horizon: float = HORIZON, grid: float = GRID
) -> np.ndarray:
    """(steps, round(horizon/grid), 2) [m]: p at start_k + j·grid for each step, interpolated
    linearly."""
    offsets = np.arange(round(horizon / grid)) * grid
    out = []
    for start, end in run.step_bounds(steps):
        if start + offsets[-1] > run.t[-1]:
            raise ValueError(
                f"the run ends at {run.t[-1]:.2f} s, before {horizon} s after the step at "
                f"{start:.2f} s"
            )
        at = start + offsets
        out.append(np.stack([np.interp(at, run.t, run.p[:, i]) for i in range(2)], axis=1))
    return np.asarray(out)


def deviation(
    run: StepRun,
    ref: StepRun,
    steps: tuple[int, ...] = STEPS,
    horizon: float = HORIZON,
    grid: float = GRID,
) -> float:
    """D [m]: RMS of ‖p_run − p_ref‖ over the aligned responses of ``steps`` (module docstring)."""
    diff = aligned_responses(run, steps, horizon, grid) - aligned_responses(
        ref, steps, horizon, grid
    )
    return float(np.sqrt(np.mean(np.sum(diff**2, axis=-1))))


def _last(run: StepRun, steps: tuple[int, ...], window: float) -> list[np.ndarray]:
    """Per step, a mask of the samples in its last ``window`` seconds [end − window, end)."""
    return [(run.t >= end - window) & (run.t < end) for _, end in run.step_bounds(steps)]


def end_peak_to_peak(
    run: StepRun, steps: tuple[int, ...] = STEPS, window: float = STEADY_STATE_WINDOW
) -> np.ndarray:
    """(steps, 2) [m]: per step and axis, max − min of p over the step's last ``window`` seconds."""
    return np.array([np.ptp(run.p[m], axis=0) for m in _last(run, steps, window)])


def end_error(
    run: StepRun, steps: tuple[int, ...] = STEPS, window: float = STEADY_STATE_WINDOW
) -> np.ndarray:
    """(steps,) [m]: per step, the mean ‖p^d − p‖ over its last ``window`` seconds."""
    return np.array(
        [
            np.mean(np.linalg.norm(run.p_des[m] - run.p[m], axis=1))
            for m in _last(run, steps, window)
        ]
    )


def response_times(
    run: StepRun, steps: tuple[int, ...] = STEPS, horizon: float = HORIZON, grid: float = GRID
) -> np.ndarray:
    """(steps,) [s]: per step, the first aligned time with ‖p^d − p‖ < 10 % of its value at the step
    (NaN: never)."""
    responses = aligned_responses(run, steps, horizon, grid)
    out = []
    for (start, _), p in zip(run.step_bounds(steps), responses):
        e = np.linalg.norm(run.setpoint_at(start) - p, axis=1)
        below = np.nonzero(e < RESPONSE_FRACTION * e[0])[0]
        out.append(below[0] * grid if len(below) else np.nan)
    return np.array(out)


def rise_times(
    run: StepRun, steps: tuple[int, ...] = STEPS, horizon: float = HORIZON, grid: float = GRID
) -> np.ndarray:
    """(steps,) [s]: per step, the 10–90 % rise time of the progress along the step (module
    docstring; NaN: never)."""
    responses = aligned_responses(run, steps, horizon, grid)
    out = []
    for (start, _), p in zip(run.step_bounds(steps), responses):
        span = run.setpoint_at(start) - p[0]
        progress = (p - p[0]) @ span / (span @ span)
        t10, t90 = (np.nonzero(progress >= f)[0] for f in (0.1, 0.9))
        out.append((t90[0] - t10[0]) * grid if len(t90) else np.nan)
    return np.array(out)


def onset_times(
    run: StepRun, steps: tuple[int, ...] = STEPS, horizon: float = HORIZON, grid: float = GRID
) -> np.ndarray:
    """(steps,) [s]: per step, the aligned time the progress along the step (:func:`rise_times`)
    first reaches 10 % (NaN: never): how long after its step instant the run starts to move."""
    responses = aligned_responses(run, steps, horizon, grid)
    out = []
    for (start, _), p in zip(run.step_bounds(steps), responses):
        span = run.setpoint_at(start) - p[0]
        t10 = np.nonzero((p - p[0]) @ span / (span @ span) >= 0.1)[0]
        out.append(t10[0] * grid if len(t10) else np.nan)
    return np.array(out)


@dataclass(frozen=True)
class Split:
    """D of several realizations of one run against one reference, split [m]: ``rms`` (RMS over the
    realizations of D), ``systematic`` (D of their mean response), ``spread`` (RMS distance of the
    realizations from their mean response); rms² = systematic² + spread². ``systematic_per_step``
    (steps,): the systematic part of each step alone."""

    rms: float
    systematic: float
    spread: float
    systematic_per_step: np.ndarray


def split_realizations(
    runs: list[StepRun],
    ref: StepRun,
    window: tuple[float, float] = (0.0, HORIZON),
    steps: tuple[int, ...] = STEPS,
    grid: float = GRID,
) -> Split:
    """D of ``runs`` (realizations of one run) against ``ref`` over the part [a, b) [s] of each
    aligned response, split into its systematic and random parts (:class:`Split`)."""
    a, b = window
    if not 0.0 <= a < b <= HORIZON or not runs:
        raise ValueError(f"need realizations and a window within [0, {HORIZON}] s, got {window}")
    keep = slice(round(a / grid), round(b / grid))
    sims = np.array([aligned_responses(r, steps, HORIZON, grid)[:, keep] for r in runs])
    real = aligned_responses(ref, steps, HORIZON, grid)[:, keep]
    mean = sims.mean(axis=0)
    bias = np.sum((mean - real) ** 2, axis=-1)
    scatter = np.sum((sims - mean) ** 2, axis=-1)
    total = np.sum((sims - real) ** 2, axis=-1)
    return Split(
        float(np.sqrt(total.mean())),
        float(np.sqrt(bias.mean())),
        float(np.sqrt(scatter.mean())),
        np.sqrt(bias.mean(axis=1)),
    )


@dataclass(frozen=True)
class ContourComparison:
    """A contour run against a reference [m, s]: D, the shift (the run's time of the reference's
    t = 0), the setpoints' RMS distance at that shift, each run's RMS of ‖p^d − p‖ over the covered
    samples (run, reference), the fraction of the reference's samples covered, and the lag by which
    the reference trails the run with D at that lag (over the samples covered at every lag
    searched)."""

    deviation: float
    shift: float
    setpoint_match: float
    rmse: tuple[float, float]
    covered: float
    lag: float
    deviation_at_lag: float


CONTOUR_LAG = 0.5
"""[s] how far the lag of a contour run is searched either way."""


def contour_deviation(
    run: StepRun, ref: StepRun, search: float = 5.0, grid: float = GRID
) -> ContourComparison:
    """``run`` against ``ref`` as the module docstring's contour deviation; the shift is searched
    on ``grid`` within ± ``search`` s of aligning the two runs' first samples, the lag on ``grid``
    within ± :data:`CONTOUR_LAG`."""

    def at(r: StepRun, t: np.ndarray, values: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, r.t, values[:, i]) for i in range(2)], axis=1)

    def covered(shift: float, margin: float = 0.0) -> np.ndarray:
        return (ref.t + shift - margin >= run.t[0]) & (ref.t + shift + margin <= run.t[-1])

    def distance(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))

    best: tuple[float, float] | None = None
    for shift in run.t[0] - ref.t[0] + np.arange(-search, search + grid / 2, grid):
        m = covered(shift)
        if m.mean() < 0.5:
            continue
        d = distance(at(run, ref.t[m] + shift, run.p_des), ref.p_des[m])
        if best is None or d < best[0]:
            best = (d, float(shift))
    if best is None:
        raise ValueError("the runs do not overlap by half the reference at any shift searched")
    match, shift = best
    m = covered(shift)
    p = at(run, ref.t[m] + shift, run.p)
    p_des = at(run, ref.t[m] + shift, run.p_des)
    inner = covered(shift, CONTOUR_LAG)
    lags = np.arange(-CONTOUR_LAG, CONTOUR_LAG + grid / 2, grid)
    at_lag = [distance(at(run, ref.t[inner] + shift - lag, run.p), ref.p[inner]) for lag in lags]
    best_lag = int(np.argmin(at_lag))
    return ContourComparison(
        distance(p, ref.p[m]),
        shift,
        match,
        (distance(p, p_des), distance(ref.p[m], ref.p_des[m])),
        float(m.mean()),
        float(lags[best_lag]),
        at_lag[best_lag],
    )


def rmse(run: StepRun) -> float:
    """[m] RMS of ‖p^d − p‖ over the run's samples before ``end``."""
    m = run.t < run.end
    return float(np.sqrt(np.mean(np.sum((run.p_des[m] - run.p[m]) ** 2, axis=1))))


@dataclass(frozen=True)
class Comparison:
    """The sim-versus-real table of one run [m, s]: D, x peak-to-peak at the end of a step (max over
    steps), end error (median over steps), median over steps of |t_run − t_ref| / t_ref of the rise
    and of the response time, and each run's RMSE."""

    deviation: float
    x_peak_to_peak: tuple[float, float]  # (run, reference)
    end_error: tuple[float, float]
    rise_time_difference: float
    response_time_difference: float
    rmse: tuple[float, float]


def compare(run: StepRun, ref: StepRun, steps: tuple[int, ...] = STEPS) -> Comparison:
    """All measures of the module docstring for ``run`` against ``ref``."""

    def relative(times) -> float:  # noqa: ANN001 - rise_times or response_times
        t_run, t_ref = times(run, steps), times(ref, steps)
        return float(np.nanmedian(np.abs(t_run - t_ref) / t_ref))

    return Comparison(
        deviation(run, ref, steps),
        (
            float(end_peak_to_peak(run, steps)[:, 0].max()),
            float(end_peak_to_peak(ref, steps)[:, 0].max()),
        ),
        (float(np.median(end_error(run, steps))), float(np.median(end_error(ref, steps)))),
        relative(rise_times),
        relative(response_times),
        (rmse(run), rmse(ref)),
    )


def overshoots(
    run: StepRun, steps: tuple[int, ...] = STEPS, horizon: float = HORIZON, grid: float = GRID
) -> np.ndarray:
    """(steps,) [m]: per step, the overshoot past the setpoint along the step's direction (module
    docstring)."""
    responses = aligned_responses(run, steps, horizon, grid)
    out = []
    for (start, _), p in zip(run.step_bounds(steps), responses):
        before = run.p_des[max(int(np.searchsorted(run.t, start, side="left")) - 1, 0)]
        target = run.setpoint_at(start)
        size = float(np.linalg.norm(target - before))
        out.append(
            max(0.0, float(np.max((p - target) @ ((target - before) / size))))
            if size > 0.0
            else np.nan
        )
    return np.array(out)


def step_deviations(
    run: StepRun,
    ref: StepRun,
    steps: tuple[int, ...] = STEPS,
    horizon: float = HORIZON,
    grid: float = GRID,
) -> np.ndarray:
    """(steps,) [m]: per step, RMS of ‖p_run − p_ref‖ over its aligned response (D of that step
    alone)."""
    diff = aligned_responses(run, steps, horizon, grid) - aligned_responses(
        ref, steps, horizon, grid
    )
    return np.sqrt(np.mean(np.sum(diff**2, axis=-1), axis=1))


@dataclass(frozen=True)
class StepTable:
    """Per-step measures of a run and a reference side by side [m, s]: the steps compared, each
    one's start in either run, D per step, and (run, reference) pairs of rise time, overshoot, end
    error and end peak-to-peak per axis ((steps, 2) each)."""

    steps: tuple[int, ...]
    start: tuple[np.ndarray, np.ndarray]
    deviation: np.ndarray
    rise_time: tuple[np.ndarray, np.ndarray]
    overshoot: tuple[np.ndarray, np.ndarray]
    end_error: tuple[np.ndarray, np.ndarray]
    peak_to_peak: tuple[np.ndarray, np.ndarray]

    def rows(self) -> list[dict[str, Any]]:
        """One dict per step (SI units; NaN as None), for JSON."""

        def num(value: float) -> float | None:
            return None if np.isnan(value) else float(value)

        out = []
        for i, k in enumerate(self.steps):
            row: dict[str, Any] = {"step": k, "deviation": num(self.deviation[i])}
            for name in ("start", "rise_time", "overshoot", "end_error"):
                pair = getattr(self, name)
                row[name] = {"run": num(pair[0][i]), "reference": num(pair[1][i])}
            row["peak_to_peak"] = {
                side: [num(v) for v in pair[i]]
                for side, pair in zip(("run", "reference"), self.peak_to_peak)
            }
            out.append(row)
        return out


def step_table(run: StepRun, ref: StepRun, steps: tuple[int, ...] = STEPS) -> StepTable:
    """Every per-step measure of ``run`` and ``ref`` (module docstring)."""

    def starts(r: StepRun) -> np.ndarray:
        return np.array([start for start, _ in r.step_bounds(steps)])

    return StepTable(
        tuple(steps),
        (starts(run), starts(ref)),
        step_deviations(run, ref, steps),
        (rise_times(run, steps), rise_times(ref, steps)),
        (overshoots(run, steps), overshoots(ref, steps)),
        (end_error(run, steps), end_error(ref, steps)),
        (end_peak_to_peak(run, steps), end_peak_to_peak(ref, steps)),
    )

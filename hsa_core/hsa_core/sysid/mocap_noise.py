"""What the reference runs say about the motion-capture noise σ, at the resolution of the data.

The reference traces (:mod:`hsa_core.runs.reference`) are matplotlib polylines that the path
simplifier thinned (matplotlib ``src/path_converters.h``, ``PathSimplifier``, run on display
coordinates in points when the figure was saved): a sample is kept only where the line leaves a
band of half-width :data:`SIMPLIFY_THRESHOLD` pt around the line being built. The last 2 s of a step
(the robot at rest) keep few vertices; white pose noise of standard deviation σ would keep more.
Where the samples lie closer on the page than the threshold, each run's direction is that of one
sample step, so sample-to-sample noise far below the threshold already ends runs.

* :func:`simplify_mask`: the samples that matplotlib's simplifier keeps, for many lines at once
  (a re-implementation of ``PathSimplifier`` for one MOVETO followed by LINETOs, finite points);
* :class:`Geometry`: one run's figure: sample spacing, display scale of time and of position;
  :func:`run_geometry`, :func:`run_windows` and :func:`observed` read a run's figure and the
  vertex counts of its rest windows; :func:`as_drawn` draws a trace as such a figure does;
* :func:`window_statistics`: Monte-Carlo vertex counts and peak-to-peak of a rest window under
  white Gaussian noise σ (plus an optional linear drift), simplified as the figure was;
* :func:`upper_bound`: the largest σ the windows' vertex counts admit (one-sided test of stochastic
  order; creep and level switching only add vertices, so they cannot make σ look smaller);
  :func:`all_noise_estimate`: the maximum-likelihood σ if every vertex were noise (an
  over-estimate), with its likelihood-ratio interval.

Positions in m, times in s, display lengths in pt (1/72 in).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass

import numpy as np

from hsa_core.runs.reference import DATA_DIR

SIMPLIFY_THRESHOLD = 0.111111111111
"""[pt] matplotlib's default ``path.simplify_threshold`` (mpl-data/matplotlibrc), in display units:
points in a PostScript file."""
WINDOW = 2.0
"""[s] the rest window at the end of each step (the data's last 2 s)."""
LEAD = 8.0
"""[s] rest before a window: a step lasts 9.5–10.4 s and its window is its last 2 s. The longer the
rest, the longer the runs the simplifier builds (their length is heavy-tailed), the fewer vertices
per σ: counting the response as rest too makes the bound on σ larger, not smaller."""
TAIL = 0.15
"""[s] rest samples after a window before the next step moves the robot (its onset delay)."""
AXES_WIDTH = {
    "20230925_092200": 191.7264,
    "20230925_093236": 263.7264,
    "20230925_094023": 263.7264,
    "20231019_143126": 263.7264,
}
"""[pt] width of the axes of each run's ``<bag>_pee`` figure (its EPS file's axes rectangle)."""
MARGIN = 0.05
"""Matplotlib's default axes margin (``axes.xmargin``): the data span 1/(1 + 2·MARGIN) of the
axes."""
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Geometry:
    """One figure's scale: sample spacing dt [s], display scale of time [pt/s] and of position
    [pt/m]."""

    dt: float
    pt_per_s: float
    pt_per_m: float

    def __post_init__(self) -> None:
        """Reject scales that are not positive and finite."""
        for name in ("dt", "pt_per_s", "pt_per_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")

    @property
    def tolerance(self) -> float:
        """[m] the simplification threshold in position units."""
        return SIMPLIFY_THRESHOLD / self.pt_per_m

    @property
    def dx(self) -> float:
        """[pt] the display step between two samples."""
        return self.dt * self.pt_per_s

    def samples(self, duration: float) -> int:
        """The number of samples in ``duration`` seconds."""
        return int(round(duration / self.dt))


@dataclass(frozen=True)
class RestWindow:
    """The last :data:`WINDOW` seconds of one step on one axis (0: x, 1: y) of a run, and the
    number of vertices its polyline kept there; flat where the line stayed within the tolerance
    band (the data's character "none")."""

    bag: str
    step: int
    axis: int
    vertices: int
    flat: bool


@dataclass(frozen=True)
class WindowStatistics:
    """Monte-Carlo statistics of a rest window: ``counts`` (replicates,) vertices kept in the
    window, ``p2p`` (replicates,) [m] its peak-to-peak on the simplified line."""

    counts: np.ndarray
    p2p: np.ndarray

    def pmf(self, n_max: int) -> np.ndarray:
        """(n_max + 1,) the count's probabilities, add-half smoothed (no zero)."""
        hist = np.bincount(np.minimum(self.counts, n_max), minlength=n_max + 1) + 0.5
        return hist / hist.sum()


@dataclass(frozen=True)
class Interval:
    """A σ estimate [m] with its interval (low, high) at :data:`CONFIDENCE`; low 0.0 where the data
    cannot tell σ from 0."""

    value: float
    low: float
    high: float


def simplify_mask(
    x: np.ndarray, y: np.ndarray, threshold: float = SIMPLIFY_THRESHOLD
) -> np.ndarray:
    """(lines, n) bool: the samples of each line (rows of x, y (lines, n) [pt], display units) that
    matplotlib's ``PathSimplifier`` keeps as vertices of the path MOVETO p0, LINETO p1 … p(n−1)."""
    x, y = np.atleast_2d(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    if x.shape != y.shape or x.shape[1] < 2:
        raise ValueError(
            f"x and y must be the same shape with >= 2 samples, got {x.shape}, {y.shape}"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    if not threshold > 0.0:
        raise ValueError(f"threshold must be > 0, got {threshold}")
    lines, n = x.shape
    rows = np.arange(lines)
    thr2 = threshold * threshold
    kept = np.zeros((lines, n), dtype=bool)
    kept[:, 0] = True  # the MOVETO
    zero_i = np.zeros(lines, dtype=np.int64)
    start, last, nxt, back = zero_i.copy(), zero_i.copy(), zero_i.copy(), zero_i.copy()
    odx, ody, norm2 = np.zeros(lines), np.zeros(lines), np.zeros(lines)
    fwd_max, back_max = np.zeros(lines), np.zeros(lines)
    last_fwd, last_back = np.zeros(lines, dtype=bool), np.zeros(lines, dtype=bool)
    for i in range(1, n):
        xi, yi = x[:, i], y[:, i]
        # no vector yet: this segment is the vector to build on
        new = norm2 == 0.0
        ndx, ndy = xi - x[rows, last], yi - y[rows, last]
        # a vector: merge the point if its distance to the line is under the threshold
        tdx, tdy = xi - x[rows, start], yi - y[rows, start]
        dot = odx * tdx + ody * tdy
        safe = np.where(new, 1.0, norm2)
        pdx, pdy = dot * odx / safe, dot * ody / safe
        perp2 = (tdx - pdx) ** 2 + (tdy - pdy) ** 2
        para2 = pdx * pdx + pdy * pdy
        merge = ~new & (perp2 < thr2)
        push = ~new & ~merge
        fwd = merge & (dot > 0.0) & (para2 > fwd_max)
        bwd = merge & (dot <= 0.0) & (para2 > back_max)
        # a push: the run's farthest points (and the last one if it was neither) become vertices
        with_back = push & (back_max > 0.0)
        kept[rows[push], nxt[push]] = True
        kept[rows[with_back], back[with_back]] = True
        lone = push & ~last_fwd & ~last_back
        kept[rows[lone], last[lone]] = True
        queued_last = np.where(with_back & ~last_fwd, back, nxt)
        queued_last = np.where(lone, last, queued_last)
        restart = new | push
        start = np.where(new, last, np.where(push, queued_last, start))
        pdx_new = np.where(new, ndx, xi - x[rows, last])
        pdy_new = np.where(new, ndy, yi - y[rows, last])
        odx, ody = np.where(restart, pdx_new, odx), np.where(restart, pdy_new, ody)
        norm2 = np.where(restart, odx * odx + ody * ody, norm2)
        fwd_max = np.where(restart, norm2, np.where(fwd, para2, fwd_max))
        back_max = np.where(restart, 0.0, np.where(bwd, para2, back_max))
        last_fwd = np.where(restart, True, fwd)
        last_back = np.where(restart, False, bwd)
        nxt = np.where(restart | fwd, i, nxt)
        back = np.where(bwd, i, back)
        last = np.full(lines, i)
    # the end of the path: the run's farthest points and the last point
    built = norm2 != 0.0
    kept[rows[built], nxt[built]] = True
    ended_back = built & (back_max > 0.0)
    kept[rows[ended_back], back[ended_back]] = True
    kept[:, n - 1] = True
    return kept


def window_statistics(
    sigma: float,
    geometry: Geometry,
    replicates: int = 400,
    drift: float = 0.0,
    seed: int = 0,
    lead: float = LEAD,
) -> WindowStatistics:
    """Vertex counts and peak-to-peak of a rest window of :data:`WINDOW` s under white Gaussian
    noise ``sigma`` [m] and a linear ``drift`` [m/s], simplified in ``geometry``'s display scale.
    The window follows ``lead`` s of the same rest and precedes :data:`TAIL` s of it."""
    if not (np.isfinite(sigma) and sigma >= 0.0):
        raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
    if replicates < 1:
        raise ValueError(f"replicates must be >= 1, got {replicates}")
    if not np.isfinite(drift):
        raise ValueError(f"drift must be finite, got {drift}")
    if not (np.isfinite(lead) and lead >= 0.0):
        raise ValueError(f"lead must be finite and >= 0, got {lead}")
    n_win, n_lead = geometry.samples(WINDOW), geometry.samples(lead)
    n = n_lead + n_win + geometry.samples(TAIL)
    t = np.arange(n) * geometry.dt
    noise = np.random.default_rng(seed).standard_normal((replicates, n))
    pos = sigma * noise + drift * t  # [m]
    x = np.broadcast_to(t * geometry.pt_per_s, pos.shape)
    kept = simplify_mask(x, pos * geometry.pt_per_m)
    window = slice(n_lead, n_lead + n_win)
    counts = kept[:, window].sum(axis=1)
    return WindowStatistics(counts, _simplified_p2p(t, pos, kept, window))


def _simplified_p2p(t: np.ndarray, pos: np.ndarray, kept: np.ndarray, window: slice) -> np.ndarray:
    """(lines,) [m] peak-to-peak over ``window`` of each line drawn through its kept samples."""
    out = np.empty(len(pos))
    for r in range(len(pos)):
        at = np.flatnonzero(kept[r])
        line = np.interp(t[window], t[at], pos[r, at])
        out[r] = np.ptp(line)
    return out


def run_geometry(bag: str) -> Geometry:
    """The figure of ``bag``'s ``_pee`` trace: its sample spacing and simplification tolerance from
    ``<bag>_step_metrics.csv``, its time scale from :data:`AXES_WIDTH` and the trace's span."""
    if bag not in AXES_WIDTH:
        raise ValueError(f"no figure geometry for run {bag!r}; known: {sorted(AXES_WIDTH)}")
    rows = _metrics(bag)
    with (DATA_DIR / f"{bag}_pee.csv").open() as f:
        t = np.array([float(r[0]) for r in list(csv.reader(f))[1:]])
    span = t[-1] - t[0]
    return Geometry(
        dt=float(rows[0]["dt_sample_est"]),
        pt_per_s=AXES_WIDTH[bag] / ((1.0 + 2.0 * MARGIN) * span),
        pt_per_m=SIMPLIFY_THRESHOLD / (float(rows[0]["simplify_tol_mm"]) * 1e-3),
    )


def run_windows(bag: str) -> list[RestWindow]:
    """Every step's rest window on x and y of ``bag`` (``<bag>_step_metrics.csv``)."""
    out = []
    for row in _metrics(bag):
        for axis, name in enumerate("xy"):
            out.append(
                RestWindow(
                    bag,
                    int(row["step"]),
                    axis,
                    int(float(row[f"n_vertices_last2s_{name}"])),
                    row[f"last2s_character_{name}"].startswith("none"),
                )
            )
    return out


def observed(bags: list[str], axis: int, flat_only: bool = False) -> list[tuple[int, Geometry]]:
    """(vertex count, geometry) of every rest window on ``axis`` of ``bags`` (only the flat ones
    with ``flat_only``)."""
    if axis not in (0, 1):
        raise ValueError(f"axis must be 0 (x) or 1 (y), got {axis}")
    return [
        (w.vertices, run_geometry(bag))
        for bag in bags
        for w in run_windows(bag)
        if w.axis == axis and (w.flat or not flat_only)
    ]


def as_drawn(t: np.ndarray, p: np.ndarray, geometry: Geometry) -> np.ndarray:
    """(n,) [m] the trace (t (n,) [s], p (n,) [m]) as the figure of ``geometry`` draws it: the line
    through the samples the simplifier keeps, at t."""
    t, p = np.asarray(t, dtype=np.float64), np.asarray(p, dtype=np.float64)
    if t.ndim != 1 or t.shape != p.shape:
        raise ValueError(f"t and p must be 1-D of the same length, got {t.shape} and {p.shape}")
    kept = simplify_mask(t * geometry.pt_per_s, p * geometry.pt_per_m)[0]
    return np.interp(t, t[kept], p[kept])


def _metrics(bag: str) -> list[dict[str, str]]:
    """The rows of ``<bag>_step_metrics.csv``."""
    path = DATA_DIR / f"{bag}_step_metrics.csv"
    if not path.is_file():
        raise ValueError(f"no step metrics for run {bag!r} ({path} is missing)")
    with path.open() as f:
        return list(csv.DictReader(f))


def _check_windows(windows: list[tuple[int, Geometry]], sigmas: np.ndarray) -> None:
    """One-line errors for an empty window list, negative counts or a bad σ grid."""
    if not windows:
        raise ValueError("no rest windows given")
    if any(n < 0 for n, _ in windows):
        raise ValueError("vertex counts must be >= 0")
    if sigmas.ndim != 1 or len(sigmas) < 2 or np.any(np.diff(sigmas) <= 0) or sigmas[0] < 0:
        raise ValueError("sigmas must be an increasing grid of >= 2 values >= 0")


def _statistics(
    windows: list[tuple[int, Geometry]], sigmas: np.ndarray, replicates: int, seed: int
) -> dict[tuple[Geometry, float], WindowStatistics]:
    """Window statistics for every distinct geometry and σ of the grid (common random numbers)."""
    return {
        (g, s): window_statistics(float(s), g, replicates, seed=seed)
        for g in {g for _, g in windows}
        for s in sigmas
    }


def _mid_cdf(simulated: np.ndarray, n: np.ndarray) -> np.ndarray:
    """P(c < n) + P(c = n)/2 of the simulated counts, at each of n."""
    ordered = np.sort(simulated)
    below = np.searchsorted(ordered, n, side="left")
    at_most = np.searchsorted(ordered, n, side="right")
    return (below + 0.5 * (at_most - below)) / len(ordered)


def upper_bound(
    windows: list[tuple[int, Geometry]],
    sigmas: np.ndarray,
    replicates: int = 400,
    seed: int = 0,
) -> tuple[float, np.ndarray]:
    """The largest σ of the grid [m] that the windows (observed vertex count, geometry) admit at
    :data:`CONFIDENCE`, and the test's p-value for every σ of ``sigmas``. One-sided test of
    stochastic order: U = Σ_j F_σ,j(n_j) (mid-distribution function of window j's count under
    white noise σ) is too small where the windows keep fewer vertices than σ would make. Creep
    and level switching only add vertices, so they make U larger, never smaller: the bound holds
    with them."""
    sigmas = np.asarray(sigmas, dtype=np.float64)
    _check_windows(windows, sigmas)
    stats = _statistics(windows, sigmas, replicates, seed)
    draws = np.random.default_rng(seed + 1).integers(replicates, size=(len(windows), 4000))
    p_values = []
    for s in sigmas:
        u_obs, u_null = 0.0, np.zeros(draws.shape[1])
        for j, (n, g) in enumerate(windows):
            simulated = stats[g, s].counts
            u_obs += float(_mid_cdf(simulated, np.array([n]))[0])
            u_null += _mid_cdf(simulated, simulated)[draws[j]]
        p_values.append(float(np.mean(u_null <= u_obs + 1e-9)))
    p_values = np.array(p_values)
    admitted = sigmas[p_values >= 1.0 - CONFIDENCE]
    if len(admitted) == len(sigmas):
        raise ValueError(f"the grid's largest σ {sigmas[-1]:.3g} m is still admitted: extend it")
    return (float(admitted.max()) if len(admitted) else 0.0), p_values


def all_noise_estimate(
    windows: list[tuple[int, Geometry]],
    sigmas: np.ndarray,
    replicates: int = 400,
    seed: int = 0,
) -> tuple[Interval, np.ndarray]:
    """The maximum-likelihood σ of the grid [m] if every vertex of the windows were noise, with
    its likelihood-ratio interval (χ²₁ at :data:`CONFIDENCE`), and the log-likelihood per σ."""
    sigmas = np.asarray(sigmas, dtype=np.float64)
    _check_windows(windows, sigmas)
    stats = _statistics(windows, sigmas, replicates, seed)
    n_max = max(n for n, _ in windows) + 1
    log_l = np.array([sum(np.log(stats[g, s].pmf(n_max)[n]) for n, g in windows) for s in sigmas])
    best = int(np.argmax(log_l))
    inside = sigmas[log_l >= log_l[best] - 0.5 * 3.841]
    if inside.max() == sigmas[-1]:
        raise ValueError(f"the interval reaches the grid's largest σ {sigmas[-1]:.3g} m: extend it")
    low = 0.0 if inside.min() == sigmas[0] else float(inside.min())
    return Interval(float(sigmas[best]), low, float(inside.max())), log_l


def world_document(sigma_x: float, sigma_y: float, runs: list[str], source: str) -> dict:
    """The mocap-noise world YAML: the upper bounds on σ_x and σ_y [m] of ``runs`` as the rest
    world's pose noise (θ keeps the declared value: its counts are not in the packaged data)."""
    return {
        "what": "the mocap's white pose noise, bounded by the reference runs' rest windows",
        "source": source,
        "runs": list(runs),
        "adopted": True,
        "status": (
            f"upper bound at {CONFIDENCE:.0%}, not identified (the data admit 0); theta keeps "
            "the declared value"
        ),
        "pose_noise_std_xy": [float(sigma_x), float(sigma_y)],
    }

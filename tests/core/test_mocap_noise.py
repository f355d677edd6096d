"""The mocap noise σ from the reference runs' simplified plot lines (hsa_core.sysid.mocap_noise).

The counterpart of the module's simplifier is matplotlib's own (``Path.cleaned(simplify=True)``,
the C++ ``PathSimplifier`` that thinned the published figures); the real data's counts are read
from the packaged step tables directly."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from hsa_core.runs.reference import DATA_DIR
from hsa_core.sysid import mocap_noise as mn

FPU = ["20230925_092200", "20230925_093236", "20230925_094023"]


def mpl_kept(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The samples matplotlib's simplifier keeps (its default threshold, display units)."""
    path = MplPath(np.column_stack([x, y]))
    assert path.simplify_threshold == mn.SIMPLIFY_THRESHOLD
    cleaned = path.cleaned(simplify=True)
    index = {(a, b): i for i, (a, b) in enumerate(zip(x, y, strict=True))}
    kept = np.zeros(len(x), dtype=bool)
    for a, b in cleaned.vertices[cleaned.codes != MplPath.STOP]:
        kept[index[(a, b)]] = True
    return kept


def mpl_window_counts(
    sigma: float, geometry: mn.Geometry, replicates: int, seed: int
) -> np.ndarray:
    """Vertices that matplotlib keeps in a 2 s rest window of white noise σ [m], with 8 s of the
    same rest before it and 0.15 s after it, drawn at ``geometry``'s scale."""
    rng = np.random.default_rng(seed)
    n_lead, n_win, n_tail = (round(d / geometry.dt) for d in (8.0, 2.0, 0.15))
    n = n_lead + n_win + n_tail
    x = np.arange(n) * geometry.dt * geometry.pt_per_s
    counts = []
    for _ in range(replicates):
        y = sigma * rng.standard_normal(n) * geometry.pt_per_m
        counts.append(int(mpl_kept(x, y)[n_lead : n_lead + n_win].sum()))
    return np.array(counts)


def step_table(bag: str) -> list[dict[str, str]]:
    """The packaged step table of ``bag``."""
    with (DATA_DIR / f"{bag}_step_metrics.csv").open() as f:
        return list(csv.DictReader(f))


def test_simplifier_keeps_the_samples_matplotlib_keeps():
    """Random lines (monotonic in x or not, noisy, repeated points, rest windows at the figures'
    scale): the kept samples are matplotlib's, exactly."""
    rng = np.random.default_rng(3)
    for trial in range(120):
        n = int(rng.integers(2, 250))
        if trial % 3 == 2:
            x = rng.normal(0.0, 1.0, n)
        else:
            x = np.cumsum(rng.uniform(0.01, 0.2, n))
        y = rng.normal(0.0, [0.001, 0.05, 0.5, 2.0][trial % 4], n)
        if trial % 5 == 0:
            y = np.round(y, 1)
        assert np.array_equal(mn.simplify_mask(x, y)[0], mpl_kept(x, y)), trial


def test_synthetic_windows_give_back_their_sigma():
    """Windows made with matplotlib's simplifier at σ = 4 µm (FPU figure): the all-noise estimate's
    interval holds 4 µm and the censored upper bound is not below it."""
    geometry = mn.run_geometry("20230925_093236")
    counts = mpl_window_counts(4e-6, geometry, 60, seed=11)
    windows = [(int(n), geometry) for n in counts]
    sigmas = np.concatenate([[0.0], np.geomspace(5e-7, 5e-5, 31)])
    est, log_l = mn.all_noise_estimate(windows, sigmas, replicates=300)
    assert est.low <= 4e-6 <= est.high
    assert est.high / max(est.low, 1e-9) < 2.5
    assert log_l.shape == sigmas.shape
    bound, _ = mn.upper_bound(windows, sigmas, replicates=300)
    assert bound >= 4e-6


def test_a_line_at_rest_or_creeping_linearly_keeps_no_vertex():
    """Noise 0: a still line and a linear creep keep no vertex in the window; the peak-to-peak of
    the creep is its slope times the window."""
    geometry = mn.run_geometry("20231019_143126")
    still = mn.window_statistics(0.0, geometry, replicates=5)
    creep = mn.window_statistics(0.0, geometry, replicates=5, drift=1e-4)
    assert still.counts.tolist() == [0] * 5 and creep.counts.tolist() == [0] * 5
    window = (geometry.samples(mn.WINDOW) - 1) * geometry.dt
    assert creep.p2p == pytest.approx(1e-4 * window)
    t = np.arange(200) * geometry.dt
    line = 3e-3 + 1e-4 * t
    assert mn.as_drawn(t, line, geometry) == pytest.approx(line, abs=1e-12)


def test_real_fpu_runs_bound_sigma_far_below_the_declared_noise():
    """FPU x: matplotlib's simplifier alone, on the number of windows that kept no vertex (8 of
    33; creep only makes empty windows rarer), rejects σ = 40 µm: that many empty windows or more
    has probability < 5 % (Poisson-binomial tail). The module's bound, from every window's count,
    lies below it and far below the declared 0.1 mm."""
    p_zero, empty = [], 0
    for bag in FPU:
        g = mn.run_geometry(bag)
        p0 = np.mean(mpl_window_counts(4e-5, g, 300, seed=5) == 0)
        for r in step_table(bag):
            p_zero.append(p0)
            empty += int(float(r["n_vertices_last2s_x"])) == 0
    assert (len(p_zero), empty) == (33, 8)
    dist = np.array([1.0])
    for p in p_zero:
        dist = np.append(dist * (1.0 - p), 0.0) + np.append(0.0, dist * p)
    assert dist[empty:].sum() < 0.05
    sigmas = np.array([0.0, 1e-6, 2e-6, 4e-6, 7e-6, 1e-5, 1.5e-5, 2e-5, 3e-5, 4e-5, 1e-4])
    bound, p_values = mn.upper_bound(mn.observed(FPU, 0), sigmas, replicates=300)
    assert 0.0 < bound < 4e-5
    assert p_values[0] == 1.0


def test_bad_input_is_refused_in_one_line():
    """Bad scales, σ, shapes, windows and grids: ValueError with a one-line message."""
    g = mn.run_geometry("20230925_093236")
    grid = np.array([0.0, 1e-6, 1e-4])
    calls = [
        lambda: mn.Geometry(0.0, 2.0, 800.0),
        lambda: mn.Geometry(0.036, float("nan"), 800.0),
        lambda: mn.window_statistics(-1e-6, g),
        lambda: mn.window_statistics(1e-6, g, replicates=0),
        lambda: mn.window_statistics(1e-6, g, lead=-1.0),
        lambda: mn.simplify_mask(np.zeros(3), np.zeros(4)),
        lambda: mn.simplify_mask(np.zeros(3), np.array([0.0, np.inf, 0.0])),
        lambda: mn.upper_bound([], grid),
        lambda: mn.upper_bound([(-1, g)], grid),
        lambda: mn.upper_bound([(0, g)], np.array([1e-6, 0.0])),
        lambda: mn.upper_bound([(60, g)], np.array([0.0, 1e-7])),
        lambda: mn.all_noise_estimate([(60, g)], np.array([0.0, 1e-7])),
        lambda: mn.run_geometry("20230101_000000"),
        lambda: mn.observed(FPU, 2),
        lambda: mn.as_drawn(np.zeros(3), np.zeros((3, 2)), g),
    ]
    for call in calls:
        with pytest.raises(ValueError) as err:
            call()
        assert "\n" not in str(err.value) and str(err.value)

"""Causal Savitzky–Golay differentiation of mocap-rate signals and the pose → configuration helper
(spec §6.3–6.4).

The estimator buffers the last N samples of a vector signal (for example q and χ_ee stacked, dim 6),
fits a polynomial of degree ``order`` by least squares and reports its first derivative **at the
newest sample** (causal end-point fit).

Rules, applied in this order on every ``update(t, x)``:

* **Rejection.** A sample whose stamp or values are not finite, whose stamp equals the newest
  accepted stamp ("duplicate stamp") or is older ("out-of-order stamp") is rejected: the buffer is
  unchanged and the returned ``Estimate`` has ``mode="rejected"``, ``value=None``,
  ``derivative=None`` and a ``reason``.
* **Gap.** If the stamp is more than ``gap_factor`` (default 1.5) nominal periods after the newest
  accepted stamp, the window is restarted: the buffer is emptied and the new sample becomes its
  first entry (``reason`` says so). So a single dropped 200 Hz frame (a 2T interval) restarts the
  window; a ``gap_factor`` of e.g. 2.5 bridges single drops with the irregular fit instead.
* **Start-up** (fewer than N samples since the last (re)start). Nothing is fitted and ``derivative``
  is ``None`` (``mode="not_ready"``); a zero velocity is never reported. Optionally
  (``startup_order`` set, e.g. 1), once at least ``order + 1`` samples exist, a least-squares
  polynomial of degree ``startup_order`` is fitted to all of them and its end-point derivative is
  reported with ``mode="startup"`` and ``ready=False``. It is noisier or more lagged than the full
  window and must not be used where a full window is required (controllers wait for ``ready``).
* **Full window, regular stamps** (``mode="regular"``). The stamps count as regular when every one
  of the N − 1 stamp intervals in the window is within ``regular_tol`` (default 1e-3) × T of the
  nominal period T. Then v = (Σ_k c_k x_k) / Δt with Δt = mean stamp interval of the window and the
  precomputed c of spec §6.4 (c = row 1 of (VᵀV)⁻¹Vᵀ, V_kj = τ_k^j, τ_k = k − (N − 1)). The rule
  bounds the deviation of every stamp from the uniform grid of spacing Δt by (N − 1)/2 × regular_tol
  × T, i.e. ≤ 1 % of T for N = 20 at the default tolerance. A signal sampled at a rate other than
  1/T is handled correctly, but always by the slower irregular path.
* **Full window, irregular stamps** (``mode="irregular"``). The polynomial is fitted by ordinary
  (equal-weight) least squares on the true stamps, normalised as τ_k = (t_k − t_newest)/Δt and
  scaled to [−1, 0] for conditioning; this costs one (order+1)×(order+1) normal-equation solve per
  sample (tens of µs instead of ≈ 4 µs). For uniform stamps it gives the same result as the regular
  path.

``value`` is always the newest accepted sample as received (not smoothed). ``ready`` is True only
for the two full-window modes. Pass stamps in seconds from a recent origin (e.g. node start): a
float64 Unix-epoch stamp resolves only ≈ 0.24 µs, which limits the relative accuracy of Δt at 200 Hz
to ≈ 5e-5.
"""

from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike


class EstimateMode(enum.StrEnum):
    """How an estimate was obtained (module docstring); values are the names on /diagnostics."""

    REGULAR = "regular"
    IRREGULAR = "irregular"
    STARTUP = "startup"
    NOT_READY = "not_ready"
    REJECTED = "rejected"


class SampleRejection(enum.StrEnum):
    """Why the estimator rejects a sample; values are the kinematics node's counter names."""

    NON_FINITE = "non-finite stamp or sample"
    DUPLICATE = "duplicate stamp"
    OUT_OF_ORDER = "out-of-order stamp"


@dataclass(frozen=True, slots=True)
class Estimate:
    """Result of one estimator update: newest sample, its time derivative (or None) and how it was
    obtained; ``reason`` says why a sample was rejected (``rejection``) or the window restarted."""

    value: np.ndarray | None
    derivative: np.ndarray | None
    ready: bool
    mode: EstimateMode
    reason: str = ""
    rejection: SampleRejection | None = None


def _rejected(rejection: SampleRejection, detail: str) -> Estimate:
    """The estimate of a rejected sample; its reason is the rejection's name and ``detail``."""
    return Estimate(None, None, False, EstimateMode.REJECTED, f"{rejection}{detail}", rejection)


def derivative_coefficients(tau: ArrayLike, order: int, xp: Any = np) -> Any:
    """Weights c with Σ c_k x_k = d/dτ at τ = 0 of the degree-``order`` least-squares polynomial
    through (τ_k, x_k); ``xp`` is numpy or jax.numpy (traceable: the batched loop's September
    estimator)."""
    tau = xp.asarray(tau, dtype=xp.float64)
    scale = xp.maximum(xp.max(xp.abs(tau)), 1.0)  # fit on u = τ/scale ∈ [−1, 0] for conditioning
    vander = (tau / scale)[:, None] ** xp.arange(order + 1)
    return xp.linalg.solve(vander.T @ vander, vander.T)[1] / scale


class SavitzkyGolayDifferentiator:
    """Causal end-point Savitzky–Golay differentiator for a vector signal, one update per sample
    (rules: module doc)."""

    def __init__(
        self,
        window: int = 20,
        order: int = 3,
        dim: int = 3,
        nominal_period: float = 0.005,
        regular_tol: float = 1e-3,
        gap_factor: float = 1.5,
        startup_order: int | None = None,
    ) -> None:
        """Precompute the regular-grid (and optional start-up) coefficients; periods in s,
        tolerances relative to T."""
        if order < 1 or window < order + 2:
            raise ValueError(
                f"need order >= 1 and window >= order + 2, got window={window}, order={order}"
            )
        if dim < 1 or not nominal_period > 0.0 or not regular_tol >= 0.0 or not gap_factor > 1.0:
            raise ValueError(
                "need dim >= 1, nominal_period > 0, regular_tol >= 0 and gap_factor > 1"
            )
        if startup_order is not None and not 1 <= startup_order < order:
            raise ValueError(f"startup_order must be in [1, order), got {startup_order}")
        self.window, self.order, self.dim = window, order, dim
        self.nominal_period, self.gap_factor, self.startup_order = (
            nominal_period,
            gap_factor,
            startup_order,
        )
        self._jitter_tol = regular_tol * nominal_period
        self._max_gap = gap_factor * nominal_period
        self.coefficients = derivative_coefficients(np.arange(window) - (window - 1.0), order)
        self.coefficients.setflags(write=False)
        self._startup_coefficients = {
            n: derivative_coefficients(np.arange(n) - (n - 1.0), startup_order)
            for n in range(order + 1, window)
            if startup_order is not None
        }
        # Double-length ring buffers: sample j is stored at j and j + N so the window is always one
        # contiguous view.
        self._x = np.zeros((2 * window, dim))
        self._t = np.zeros(2 * window)
        # per stamp interval in the window: deviates from the nominal period
        self._off_grid = [False] * (window - 1)
        self._ones = np.ones(dim)
        self.reset()

    def reset(self) -> None:
        """Empty the buffer; the next sample starts a new window."""
        self._count = 0
        self._head = -1
        self._t_last = -math.inf
        self._off_grid[:] = [False] * (self.window - 1)
        self._n_off_grid = 0

    @property
    def n_samples(self) -> int:
        """Number of samples in the current window (at most N)."""
        return min(self._count, self.window)

    def update(self, t: float, x: ArrayLike) -> Estimate:
        """Add the sample x taken at stamp t [s] and return the derivative estimate at t."""
        x = np.array(x, dtype=np.float64)
        if x.shape != (self.dim,):
            raise ValueError(f"expected a sample of shape ({self.dim},), got {x.shape}")
        t = float(t)
        # one NaN or inf makes the sum non-finite (a sum is cheaper than np.isfinite(x).all())
        if not (math.isfinite(t) and math.isfinite(x.dot(self._ones))):
            return _rejected(SampleRejection.NON_FINITE, "")
        step = t - self._t_last
        if step == 0.0:
            return _rejected(SampleRejection.DUPLICATE, "")
        if step < 0.0:
            return _rejected(
                SampleRejection.OUT_OF_ORDER, f" ({-step:.6g} s older than the newest)"
            )
        reason = ""
        if self._count and step > self._max_gap:
            reason = f"gap of {step:.6g} s > {self.gap_factor} nominal periods: window restarted"
            self.reset()
        n_win = self.window
        head = self._head = (self._head + 1) % n_win
        self._x[head] = x
        self._x[head + n_win] = x
        self._t[head] = t
        self._t[head + n_win] = t
        if self._count:
            slot = (self._count - 1) % (n_win - 1)
            off_grid = abs(step - self.nominal_period) > self._jitter_tol
            self._n_off_grid += off_grid - self._off_grid[slot]
            self._off_grid[slot] = off_grid
        self._t_last = t
        self._count += 1
        if self._count < n_win:
            return self._startup(x, self._count, reason)
        lo = head + 1
        if not self._n_off_grid:
            derivative = self.coefficients.dot(self._x[lo : lo + n_win]) / (
                (t - self._t[lo]) / (n_win - 1)
            )
            return Estimate(x, derivative, True, EstimateMode.REGULAR, reason)
        derivative = self._fit_true_stamps(lo, n_win, self.order)
        return Estimate(x, derivative, True, EstimateMode.IRREGULAR, reason)

    def _startup(self, x: np.ndarray, n: int, reason: str) -> Estimate:
        """Estimate while the window is filling: nothing, or the optional lower-order fit."""
        if self.startup_order is None or n < self.order + 1:
            return Estimate(x, None, False, EstimateMode.NOT_READY, reason)
        lo = self._head + 1 + self.window - n
        if not self._n_off_grid:
            mean_dt = (self._t[lo + n - 1] - self._t[lo]) / (n - 1)
            derivative = self._startup_coefficients[n].dot(self._x[lo : lo + n]) / mean_dt
        else:
            derivative = self._fit_true_stamps(lo, n, self.startup_order)
        return Estimate(x, derivative, False, EstimateMode.STARTUP, reason)

    def _fit_true_stamps(self, lo: int, n: int, order: int) -> np.ndarray:
        """End-point derivative of a least-squares fit on the true stamps of buffer rows lo …
        lo+n−1."""
        stamps = self._t[lo : lo + n]
        mean_dt = (stamps[-1] - stamps[0]) / (n - 1)
        c = derivative_coefficients((stamps - stamps[-1]) / mean_dt, order)
        return c.dot(self._x[lo : lo + n]) / mean_dt


@functools.cache
def _configuration_fn() -> Any:
    """Jitted closed-form IK, built on first use so that this module imports without the model."""
    import jax

    from hsa_core.model.kinematics import inverse_kinematics

    return jax.jit(inverse_kinematics)


def configuration_from_pose(params: Any, chiee: ArrayLike) -> np.ndarray:
    """Configuration q = ξ(χ_ee) − ξ_eq (spec §6.3) of an EE pose [x, y, θ] in {0} with the run's
    rest strains.

    ``hsa_core.model.kinematics.inverse_kinematics`` already returns strains minus ``params.xi_eq``
    (docs/core_api.md), so this is that function compiled once (per parameter structure), fed and
    returning NumPy arrays.
    """
    return np.asarray(_configuration_fn()(params, np.asarray(chiee, dtype=np.float64)))

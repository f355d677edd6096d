"""Reachability of a target: the polygon of end-effector positions the robot can hold (no model,
NumPy only).

The forward map phi -> p_ee of the robot is one-to-one on the box [0, phi_max]^2, so the reachable
set is the polygon traced by the images of the box edges (:func:`boundary_phis`).
:class:`ReachabilityRegion` accepts a point inside that polygon or within ``margin`` of it; a test
costs tens of microseconds. The planner builds it from its own equilibria
(:mod:`hsa_core.task.planning`); :mod:`hsa_core.analysis.workspace` maps the whole workspace.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def boundary_phis(phi_lo: ArrayLike, phi_hi: ArrayLike, n_per_edge: int = 32) -> np.ndarray:
    """Points (4 n, 2) walking once around the edges of the box [phi_lo, phi_hi] (each corner
    once)."""
    lo, hi = np.asarray(phi_lo, float), np.asarray(phi_hi, float)
    s = np.linspace(0.0, 1.0, n_per_edge, endpoint=False)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return np.concatenate(
        [a + s[:, None] * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0))]
    )


class ReachabilityRegion:
    """Polygon of reachable EE positions (boundary image of the phi box) inflated by `margin`
    [m]."""

    def __init__(self, boundary: ArrayLike, margin: float) -> None:
        """Keep the closed polygon `boundary` (M, 2) [m] and the margin [m]."""
        self.boundary = np.asarray(boundary, dtype=float)
        if self.boundary.ndim != 2 or self.boundary.shape[1] != 2 or len(self.boundary) < 3:
            raise ValueError(
                f"boundary must be (M >= 3, 2) positions, got shape {self.boundary.shape}"
            )
        if not margin >= 0.0:
            raise ValueError(f"margin must be >= 0, got {margin!r}")
        self.margin = float(margin)
        self._a = self.boundary
        self._b = np.roll(self.boundary, -1, axis=0)
        self._d = self._b - self._a
        self._dd = np.maximum(np.sum(self._d**2, axis=1), 1e-300)
        self._box_lo = self.boundary.min(axis=0) - self.margin
        self._box_hi = self.boundary.max(axis=0) + self.margin

    def inside(self, p: ArrayLike) -> bool:
        """Inside the polygon (even-odd rule), without margin."""
        x, y = np.asarray(p, dtype=float)
        a, b = self._a, self._b
        crosses = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        return bool(np.count_nonzero(crosses & (x < x_cross)) % 2)

    def distance(self, p: ArrayLike) -> float:
        """Distance from p to the polygon's boundary [m]."""
        p = np.asarray(p, dtype=float)
        s = np.clip(np.sum((p - self._a) * self._d, axis=1) / self._dd, 0.0, 1.0)
        return float(np.sqrt(np.min(np.sum((self._a + s[:, None] * self._d - p) ** 2, axis=1))))

    def contains(self, p: ArrayLike) -> bool:
        """True unless p is certainly unreachable: outside the polygon by more than the margin."""
        x, y = np.asarray(p, dtype=float)
        if not (
            self._box_lo[0] <= x <= self._box_hi[0] and self._box_lo[1] <= y <= self._box_hi[1]
        ):
            return False  # outside the inflated bounding box: no polygon arithmetic needed
        return self.inside(p) or self.distance(p) <= self.margin

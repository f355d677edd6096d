"""The reachable workspace: static equilibria of the end effector over phi in [0, phi_max]^2 (the paper's Fig. 1b).

* :func:`workspace_map` solves the static equilibrium G + K - alpha = 0 on a phi grid and returns the EE poses with the
  mean actuation magnitude (|phi1| + |phi2|) / 2 of each; :func:`plot_workspace` draws them coloured by it, with three
  sample configurations (backbone, both virtual rods, platform). The paper does not list the phi of its three
  samples; ours are the two extreme bends and the half-twisted straight robot (SAMPLE_PHI_FRACTIONS).
* :class:`ReachabilityRegion` is the fast test the planner uses: the forward map phi -> p_ee of the robot is one-to-one
  on the box, so the reachable set is the polygon traced by the images of the box edges. A point is accepted when
  it lies inside that polygon or within `margin` of it; a test costs tens of microseconds.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from hsa_core import kinematics
from hsa_core.params import HsaParams

SAMPLE_PHI_FRACTIONS = ((1.0, 0.0), (0.5, 0.5), (0.0, 1.0))
"""Sample configurations drawn on the map, as fractions of phi_max: bent to +x, straight half-twisted, bent to -x."""


def boundary_phis(phi_lo: ArrayLike, phi_hi: ArrayLike, n_per_edge: int = 32) -> np.ndarray:
    """Points (4 n, 2) walking once around the edges of the box [phi_lo, phi_hi] (each corner once)."""
    lo, hi = np.asarray(phi_lo, float), np.asarray(phi_hi, float)
    s = np.linspace(0.0, 1.0, n_per_edge, endpoint=False)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return np.concatenate([a + s[:, None] * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0))])


class ReachabilityRegion:
    """Polygon of reachable EE positions (boundary image of the phi box) inflated by `margin` [m]."""

    def __init__(self, boundary: ArrayLike, margin: float) -> None:
        """Keep the closed polygon `boundary` (M, 2) [m] and the margin [m]."""
        self.boundary = np.asarray(boundary, dtype=float)
        if self.boundary.ndim != 2 or self.boundary.shape[1] != 2 or len(self.boundary) < 3:
            raise ValueError(f"boundary must be (M >= 3, 2) positions, got shape {self.boundary.shape}")
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
        if not (self._box_lo[0] <= x <= self._box_hi[0] and self._box_lo[1] <= y <= self._box_hi[1]):
            return False  # outside the inflated bounding box: no polygon arithmetic needed
        return self.inside(p) or self.distance(p) <= self.margin


@dataclasses.dataclass(frozen=True)
class WorkspaceMap:
    """Equilibria on an n x n phi grid: phi (n, n, 2), chiee (n, n, 3), q (n, n, 3), mean |phi| (n, n), residual."""

    phi: np.ndarray
    chiee: np.ndarray
    q: np.ndarray
    mean_actuation: np.ndarray
    residual: np.ndarray
    material: str

    def save_npz(self, path: Path) -> Path:
        """Write every field as an array (material as a string)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, phi=self.phi, chiee=self.chiee, q=self.q, mean_actuation=self.mean_actuation,
                 residual=self.residual, material=np.asarray(self.material))
        return path


@jax.jit
def _equilibria(params: HsaParams, phis: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Static equilibria (q, EE pose, residual norm) for a batch of phi, each solved from q = 0."""
    from hsa_core.planning import static_equilibrium  # planning imports this module for its reachability test

    q, res = jax.vmap(static_equilibrium, in_axes=(None, 0, None))(params, phis, jnp.zeros(3))
    return q, jax.vmap(lambda qq: kinematics.end_effector_pose(params, qq))(q), res


def equilibrium_poses(params: HsaParams, phis: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q (N, 3), EE pose (N, 3) and residual norm (N,) of the static equilibria for phis (N, 2)."""
    q, chiee, res = _equilibria(params, jnp.asarray(phis, dtype=jnp.float64))
    return np.asarray(q), np.asarray(chiee), np.asarray(res)


def workspace_map(params: HsaParams, n: int = 41) -> WorkspaceMap:
    """Equilibria of the EE over an n x n grid of phi in [0, phi_max]^2, with the mean actuation magnitude."""
    grid = np.linspace(0.0, 1.0, n)
    u = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1)
    phis = u * np.asarray(params.phi_max) * np.asarray(params.h)
    q, chiee, res = equilibrium_poses(params, phis.reshape(-1, 2))
    return WorkspaceMap(phis, chiee.reshape(n, n, 3), q.reshape(n, n, 3), np.mean(np.abs(phis), axis=-1),
                        res.reshape(n, n), params.material)


def _outline(params: HsaParams, q: np.ndarray) -> dict[str, np.ndarray]:
    """Backbone, rods and platform corners of configuration q in {0} for drawing."""
    s = np.linspace(0.0, float(params.l), 30)
    backbone = np.asarray(kinematics.backbone_pose(params, q, s))[:, :2]
    rods = np.asarray(kinematics.rod_positions(params, q, s))
    tip = np.asarray(kinematics.backbone_pose(params, q, float(params.l)))
    w, h_p = float(params.platform_size[0]), float(params.platform_size[1])
    top, bottom = float(params.l_dc), float(params.l_dc) + h_p
    local = np.array([[-w / 2, top], [w / 2, top], [w / 2, bottom], [-w / 2, bottom], [-w / 2, top]])
    platform = tip[:2] + np.asarray(kinematics.rotate(tip[2], local))
    cap_lines = [np.stack([rods[-1, i], rods[-1, i] + np.asarray(kinematics.rotate(tip[2], [0.0, top]))])
                 for i in range(2)]
    return {"backbone": backbone, "rod1": rods[:, 0], "rod2": rods[:, 1], "platform": platform,
            "cap1": cap_lines[0], "cap2": cap_lines[1]}


def plot_workspace(params: HsaParams, wmap: WorkspaceMap, path: Path) -> Path:
    """Figure: reachable EE positions coloured by mean actuation magnitude, with the three sample configurations.

    The samples are the grid nodes nearest to SAMPLE_PHI_FRACTIONS (exact for an odd grid size n).
    """
    from hsa_core.plotting import plt, save  # matplotlib is imported only when a figure is drawn

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    pts = wmap.chiee.reshape(-1, 3)
    sc = ax.scatter(pts[:, 0] * 1e3, pts[:, 1] * 1e3, c=wmap.mean_actuation.reshape(-1), s=8, cmap="viridis")
    fig.colorbar(sc, ax=ax, label="mean actuation magnitude (|phi1| + |phi2|) / 2 [rad]")
    n = wmap.phi.shape[0]
    nodes = [tuple(round(f * (n - 1)) for f in fractions) for fractions in SAMPLE_PHI_FRACTIONS]
    samples = [(wmap.phi[i, j], wmap.q[i, j], wmap.chiee[i, j]) for i, j in nodes]
    for k, (phi, qk, pose) in enumerate(samples):
        color = plt.cm.tab10(k + 1)
        shapes = _outline(params, qk)
        for name, xy in shapes.items():
            style = {"lw": 2.5} if name == "backbone" else {"lw": 1.0}
            ax.plot(xy[:, 0] * 1e3, xy[:, 1] * 1e3, "-", color=color, **style)
        ax.plot(pose[0] * 1e3, pose[1] * 1e3, "o", color=color, ms=7, mec="k",
                label=f"phi = [{phi[0]:.2f}, {phi[1]:.2f}] rad")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm] (down along the hanging robot)")
    ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_title(f"{wmap.material.upper()} workspace: EE equilibria for phi in [0, phi_max]^2")
    ax.legend(fontsize=8, loc="lower left")
    return save(fig, path)

"""The reachable workspace: static equilibria of the end effector over phi in [0, phi_max]^2 (the
paper's Fig. 1b).

* :func:`workspace_map` solves the static equilibrium G + K - alpha = 0 on a phi grid and returns
  the EE poses with the mean actuation magnitude (|phi1| + |phi2|) / 2 of each;
  :func:`plot_workspace` draws them coloured by it, with three sample configurations (backbone, both
  virtual rods, platform). The paper does not list the phi of its three samples; ours are the two
  extreme bends and the half-twisted straight robot (SAMPLE_PHI_FRACTIONS).
* the planner's fast reachability test is :class:`hsa_core.task.reachability.ReachabilityRegion`
  (re-exported here).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from hsa_core.model import kinematics
from hsa_core.model.params import HsaParams
from hsa_core.task.planning import static_equilibrium
from hsa_core.task.reachability import ReachabilityRegion, boundary_phis

__all__ = [
    "ReachabilityRegion",
    "WorkspaceMap",
    "boundary_phis",
    "equilibrium_poses",
    "plot_workspace",
    "workspace_map",
]

SAMPLE_PHI_FRACTIONS = ((1.0, 0.0), (0.5, 0.5), (0.0, 1.0))
"""Sample configurations drawn on the map, as fractions of phi_max: bent to +x, straight
half-twisted, bent to -x."""


@dataclasses.dataclass(frozen=True)
class WorkspaceMap:
    """Equilibria on an n x n phi grid: phi (n, n, 2), chiee (n, n, 3), q (n, n, 3), mean |phi| (n,
    n), residual."""

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
        np.savez(
            path,
            phi=self.phi,
            chiee=self.chiee,
            q=self.q,
            mean_actuation=self.mean_actuation,
            residual=self.residual,
            material=np.asarray(self.material),
        )
        return path


@jax.jit
def _equilibria(params: HsaParams, phis: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Static equilibria (q, EE pose, residual norm) for a batch of phi, each solved from q = 0."""

    q, res = jax.vmap(static_equilibrium, in_axes=(None, 0, None))(params, phis, jnp.zeros(3))
    return q, jax.vmap(lambda qq: kinematics.end_effector_pose(params, qq))(q), res


def equilibrium_poses(
    params: HsaParams, phis: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q (N, 3), EE pose (N, 3) and residual norm (N,) of the static equilibria for phis (N, 2)."""
    q, chiee, res = _equilibria(params, jnp.asarray(phis, dtype=jnp.float64))
    return np.asarray(q), np.asarray(chiee), np.asarray(res)


def workspace_map(params: HsaParams, n: int = 41) -> WorkspaceMap:
    """Equilibria of the EE over an n x n grid of phi in [0, phi_max]^2, with the mean actuation
    magnitude."""
    grid = np.linspace(0.0, 1.0, n)
    u = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1)
    phis = u * np.asarray(params.phi_max) * np.asarray(params.h)
    q, chiee, res = equilibrium_poses(params, phis.reshape(-1, 2))
    return WorkspaceMap(
        phis,
        chiee.reshape(n, n, 3),
        q.reshape(n, n, 3),
        np.mean(np.abs(phis), axis=-1),
        res.reshape(n, n),
        params.material,
    )


def _outline(params: HsaParams, q: np.ndarray) -> dict[str, np.ndarray]:
    """Backbone, rods and platform corners of configuration q in {0} for drawing."""
    s = np.linspace(0.0, float(params.l), 30)
    backbone = np.asarray(kinematics.backbone_pose(params, q, s))[:, :2]
    rods = np.asarray(kinematics.rod_positions(params, q, s))
    tip = np.asarray(kinematics.backbone_pose(params, q, float(params.l)))
    w, h_p = float(params.platform_size[0]), float(params.platform_size[1])
    top, bottom = float(params.l_dc), float(params.l_dc) + h_p
    local = np.array(
        [[-w / 2, top], [w / 2, top], [w / 2, bottom], [-w / 2, bottom], [-w / 2, top]]
    )
    platform = tip[:2] + np.asarray(kinematics.rotate(tip[2], local))
    cap_lines = [
        np.stack([rods[-1, i], rods[-1, i] + np.asarray(kinematics.rotate(tip[2], [0.0, top]))])
        for i in range(2)
    ]
    return {
        "backbone": backbone,
        "rod1": rods[:, 0],
        "rod2": rods[:, 1],
        "platform": platform,
        "cap1": cap_lines[0],
        "cap2": cap_lines[1],
    }


def plot_workspace(params: HsaParams, wmap: WorkspaceMap, path: Path) -> Path:
    """Figure: reachable EE positions coloured by mean actuation magnitude, with the three sample
    configurations.

    The samples are the grid nodes nearest to SAMPLE_PHI_FRACTIONS (exact for an odd grid size n).
    """
    from matplotlib import colormaps

    from hsa_core.analysis.plotting import save, subplots  # matplotlib only where a figure is drawn

    fig, ax = subplots(figsize=(6.5, 6.5))
    pts = wmap.chiee.reshape(-1, 3)
    sc = ax.scatter(
        pts[:, 0] * 1e3, pts[:, 1] * 1e3, c=wmap.mean_actuation.reshape(-1), s=8, cmap="viridis"
    )
    fig.colorbar(sc, ax=ax, label="mean actuation magnitude (|phi1| + |phi2|) / 2 [rad]")
    n = wmap.phi.shape[0]
    nodes = [tuple(round(f * (n - 1)) for f in fractions) for fractions in SAMPLE_PHI_FRACTIONS]
    samples = [(wmap.phi[i, j], wmap.q[i, j], wmap.chiee[i, j]) for i, j in nodes]
    for k, (phi, qk, pose) in enumerate(samples):
        color = colormaps["tab10"](k + 1)
        shapes = _outline(params, qk)
        for name, xy in shapes.items():
            style = {"lw": 2.5} if name == "backbone" else {"lw": 1.0}
            ax.plot(xy[:, 0] * 1e3, xy[:, 1] * 1e3, "-", color=color, **style)
        ax.plot(
            pose[0] * 1e3,
            pose[1] * 1e3,
            "o",
            color=color,
            ms=7,
            mec="k",
            label=f"phi = [{phi[0]:.2f}, {phi[1]:.2f}] rad",
        )
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm] (down along the hanging robot)")
    ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_title(f"{wmap.material.upper()} workspace: EE equilibria for phi in [0, phi_max]^2")
    ax.legend(fontsize=8, loc="lower left")
    return save(fig, path)

"""Figures like the paper's, drawn from a RunLog (offline experiment or recorded bag), written as PNG files.

* ``end_effector``: x and y of the end-effector against the reference over time;
* ``configuration``: κ, σ_sh, σ_ax against q^d;
* ``collocated``: ϑ₁, ϑ₂ against ϑ^d;
* ``actuation``: φ₁, φ₂ (saturated command) against φ^ss, with the limits;
* ``path``: the Cartesian end-effector path over the reference (used for contour trajectories).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: figures are files
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hsa_core.runlog import RunLog  # noqa: E402

MM = 1e3  # m → mm for axes


def save(fig: plt.Figure, path: Path | str) -> Path:
    """Lay out, write (creating missing directories) and close a figure; returns the path."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _title(log: RunLog, what: str) -> str:
    who = " · ".join(v for v in (log.meta.get("material", ""), log.meta.get("controller", "")) if v)
    return f"{what} ({who})" if who else what


def end_effector(log: RunLog, path: Path) -> Path:
    """End-effector position (x, y) vs reference over time."""
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for k, (ax, label) in enumerate(zip(axes, ("x", "y"))):
        ax.plot(log.t, log.chiee_des[:, k] * MM, "--", color="k", lw=1.2, label="reference")
        ax.plot(log.t, log.chiee[:, k] * MM, color="C0", lw=1.0, label="measured")
        ax.set_ylabel(f"{label}_ee [mm]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best")
    axes[0].set_title(_title(log, "End-effector position"))
    axes[-1].set_xlabel("t [s]")
    return save(fig, path)


def configuration(log: RunLog, path: Path) -> Path:
    """Configuration q vs q^d over time."""
    labels = ("κ_be [1/m]", "σ_sh [-]", "σ_ax [-]")
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 6))
    for k, ax in enumerate(axes):
        ax.plot(log.t, log.q_des[:, k], "--", color="k", lw=1.2, label="q^d")
        ax.plot(log.t, log.q[:, k], color="C1", lw=1.0, label="q")
        ax.set_ylabel(labels[k])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best")
    axes[0].set_title(_title(log, "Configuration"))
    axes[-1].set_xlabel("t [s]")
    return save(fig, path)


def collocated(log: RunLog, path: Path) -> Path:
    """Collocated actuation coordinates ϑ₁, ϑ₂ vs ϑ^d over time."""
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for k, ax in enumerate(axes):
        ax.plot(log.t, log.varphi_des[:, k], "--", color="k", lw=1.2, label="ϑ^d")
        ax.plot(log.t, log.varphi[:, k], color="C2", lw=1.0, label="ϑ")
        ax.set_ylabel(f"ϑ_{k + 1} [N m/rad]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best")
    axes[0].set_title(_title(log, "Collocated coordinates"))
    axes[-1].set_xlabel("t [s]")
    return save(fig, path)


def actuation(log: RunLog, path: Path, phi_max: float | None = None) -> Path:
    """Commanded twist φ (saturated) vs the planner's φ^ss over time."""
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    for k, ax in enumerate(axes):
        ax.plot(log.t, log.phi_ss[:, k], "--", color="k", lw=1.2, label="φ^ss")
        ax.plot(log.t, log.phi_sat[:, k], color="C3", lw=1.0, label="φ (command)")
        if phi_max is not None:
            ax.axhline(phi_max, color="grey", lw=0.8, ls=":")
            ax.axhline(0.0, color="grey", lw=0.8, ls=":")
        ax.set_ylabel(f"φ_{k + 1} [rad]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best")
    axes[0].set_title(_title(log, "Actuation"))
    axes[-1].set_xlabel("t [s]")
    return save(fig, path)


def cartesian_path(log: RunLog, path: Path) -> Path:
    """End-effector path in the plane over the reference path (y down, as the robot hangs)."""
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(log.chiee_des[:, 0] * MM, log.chiee_des[:, 1] * MM, "--", color="k", lw=1.2, label="reference")
    ax.plot(log.chiee[:, 0] * MM, log.chiee[:, 1] * MM, color="C0", lw=1.0, label="measured")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.invert_yaxis()
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    ax.set_title(_title(log, "End-effector path"))
    return save(fig, path)


def all_figures(log: RunLog, out_dir: Path, prefix: str = "", phi_max: float | None = None,
                contour: bool = False) -> list[Path]:
    """Write every figure of a run into ``out_dir``; return the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [
        end_effector(log, out_dir / f"{prefix}end_effector.png"),
        configuration(log, out_dir / f"{prefix}configuration.png"),
        collocated(log, out_dir / f"{prefix}collocated.png"),
        actuation(log, out_dir / f"{prefix}actuation.png", phi_max),
    ]
    if contour:
        paths.append(cartesian_path(log, out_dir / f"{prefix}path.png"))
    return paths



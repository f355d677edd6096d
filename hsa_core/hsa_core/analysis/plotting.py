"""Figures of closed-loop runs for a paper, drawn from RunLogs (offline experiment or recorded bag),
as PDF and PNG.

Per run (:func:`all_figures`, each file as ``<name>.pdf`` and ``<name>.png``):

* ``end_effector``: x_ee and y_ee against the reference over the run, with ‖e‖(t) on a log scale
  below (so that sub-millimetre errors and 10 mm steps are readable in one panel) and the RMSE
  marked;
* ``steps``: one panel per step, from 0.25 s before to 2 s after the setpoint change, p_ee − p^d_k
  in x and y: the 0.2–0.5 s transients that the full-run scale hides (step runs only);
* ``path``: the x–y plane, the measured path over the setpoints (or the reference path of a
  contour);
* ``actuation``: φ₁, φ₂ commanded (saturated), measured (``/hsa/phi_present``, when the log has it),
  φ^ss (only for the laws that have one: not the PID) and the limits [0, φ_max];
* ``configuration``: κ_be, σ_sh, σ_ax against q^d; ``collocated``: ϑ₁, ϑ₂ against ϑ^d.

Several runs over each other (:func:`overlay_figures`, files ``overlay_<name>``): end effector with
‖e‖, steps (the distance to each step's target), path and actuation, one colour per run with the
law, material, setup and RMSE in the legend. References are drawn dashed and on top of the measured
lines. Titles name the law as in the paper (P-satI-D, P-satI-D + GC, PID, "+ EE integral"), the
material, sim or robot, and the RMSE; every axis label carries its SI unit. Lines that stand for a
run carry ``gid = "run:<index>"``, references ``gid = "reference"`` (tests count them).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from io import BytesIO
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from fontTools.ttLib import TTFont
from matplotlib.axes import Axes
from matplotlib.backends import _backend_pdf_ps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hsa_core.analysis.metrics import step_bounds, tracking_rmse
from hsa_core.runs.runlog import RunLog

MM = 1e3  # m → mm for axes
FORMATS = ("pdf", "png")
PNG_DPI = 200
STEP_WINDOW = (-0.25, 2.0)  # s around each setpoint change in the step figures
STEP_COLUMNS = 4  # panels per row of the step figures
MAX_STEPS = 20  # more setpoints than this is a contour: no step figure
ERROR_FLOOR = 1e-3  # mm, lower clip of ‖e‖ on the log axis (a tick exactly on the target)
STYLE = {
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "lines.linewidth": 1.0,
    "legend.framealpha": 0.85,
    "pdf.fonttype": 42,
    "mathtext.fontset": "dejavusans",
}
REFERENCE = {
    "color": "k",
    "ls": (0, (4, 2)),
    "lw": 1.1,
    "zorder": 4,
    "gid": "reference",  # dashed, on top
}
SETPOINT = {**REFERENCE, "drawstyle": "steps-post"}  # setpoints hold from one tick to the next
LIMIT = {"color": "0.35", "ls": "-.", "lw": 0.9, "zorder": 1}
LAW_NAMES = {"psatid": "P-satI-D", "psatid_gc": "P-satI-D + GC", "pid": "PID"}
EE_INTEGRAL = "EE integral"
AXES_XY = (r"$x_\mathrm{ee}$", r"$y_\mathrm{ee}$")


def law_name(controller: str, ee_integral: bool = False) -> str:
    """The law as the paper names it, from the controller field ("psatid", "pid", "psatid+eei",
    "psatid + EE …")."""
    laws = []
    for part in controller.split(","):
        kind, plus, rest = part.strip().partition("+")
        kind = kind.strip()
        extension = ee_integral or (bool(plus) and rest.strip() in ("eei", EE_INTEGRAL))
        name = LAW_NAMES.get(kind, kind or "law ?")
        laws.append(f"{name} + {EE_INTEGRAL}" if extension else name)
    return " / ".join(laws)


def has_phi_ss(log: RunLog) -> bool:
    """Whether the run's law uses a steady-state actuation φ^ss (the collocated laws; not the
    PID)."""
    return not any(
        part.strip().startswith("pid") for part in log.meta.get("controller", "").split(",")
    )


@dataclass(frozen=True)
class RunLabel:
    """What a figure says about a run: the law, the material, sim or robot, and the RMSE [m]."""

    law: str
    material: str
    setup: str
    rmse: float

    @classmethod
    def of(cls, log: RunLog, rmse: float | None = None) -> RunLabel:
        """Label from the log's meta (controller, ee_integral, material, setup); RMSE over the log
        unless given."""
        meta = log.meta
        law = law_name(meta.get("controller", ""), meta.get("ee_integral", "").lower() == "true")
        # offline experiments are simulations
        setup = meta.get("setup") or ("sim" if "bag" not in meta else "")
        if rmse is None:
            rmse = tracking_rmse(log.chiee_des[:, :2], log.chiee[:, :2])
        return cls(law, meta.get("material", "").upper(), setup, float(rmse))

    @property
    def short(self) -> str:
        """'P-satI-D, FPU, sim: RMSE 3.02 mm' (legends)."""
        who = ", ".join(v for v in (self.law, self.material, self.setup) if v)
        return f"{who}: RMSE {self.rmse * MM:.2f} mm"

    def title(self, what: str) -> str:
        """Figure title: what is shown, then the run."""
        return f"{what}\n{self.short}"


def subplots(
    *args: Any, figsize: tuple[float, float] | None = None, layout: str | None = None, **kwargs: Any
) -> tuple[Figure, Any]:
    """A figure and its axes, as ``pyplot.subplots`` takes them, made without pyplot: no
    backend is chosen and nothing global changes; ``savefig`` picks each format's writer."""
    fig = Figure(figsize=figsize, layout=layout)
    return fig, fig.subplots(*args, **kwargs)


_SUBSET_FONT = _backend_pdf_ps.get_glyphs_subset
"""matplotlib's Type 42 font subsetting (a font file and glyph set → the subset font)."""


@lru_cache(maxsize=256)
def _font_subset(fontfile: Any, glyphs: frozenset[int]) -> tuple[bytes, dict[int, int]]:
    """The subset font's file bytes and glyph index map, computed once per font and glyph set."""
    with _SUBSET_FONT(fontfile, glyphs) as subset:
        return _backend_pdf_ps.font_as_file(subset.font).getvalue(), dict(subset.glyph_index_map)


@contextmanager
def _stored_subset(fontfile: Any, glyphs: Collection[int]) -> Iterator[Any]:
    """``get_glyphs_subset`` from :func:`_font_subset`: the same font (written again, byte for byte:
    no new timestamp) and index map."""
    data, index_map = _font_subset(fontfile, frozenset(glyphs))
    with TTFont(BytesIO(data), recalcTimestamp=False) as font:
        yield _backend_pdf_ps.SubsetResults(font, index_map)


@contextmanager
def _font_subsets_reused() -> Iterator[None]:
    """While a figure is written: the PDF writer subsets each font for a glyph set once per process
    (fontTools parses the whole font file for every subset, most of a PDF's writing time; figures
    of one run share their glyph sets). The files are byte for byte the same."""
    _backend_pdf_ps.get_glyphs_subset = _stored_subset
    try:
        yield
    finally:
        _backend_pdf_ps.get_glyphs_subset = _SUBSET_FONT


def save(fig: Figure, path: Path | str) -> Path:
    """Lay out and write a figure (creating missing directories) in ``path``'s format; returns
    the path."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _font_subsets_reused():
        fig.savefig(path, dpi=120)
    return path


def save_all_formats(fig: Figure, stem: Path) -> list[Path]:
    """Write ``stem.pdf`` (vector, for the paper) and ``stem.png`` (for a quick look), cropped to
    the drawing as ``bbox_inches="tight"`` crops it.

    The layout and the crop are computed once, with the PNG's renderer, and both files are drawn
    from them (``savefig`` would lay out and measure the figure again for each file).
    """
    stem.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.set_dpi(PNG_DPI)
    fig.draw_without_rendering()  # runs the layout engine
    bbox = fig.get_tightbbox().padded(matplotlib.rcParams["savefig.pad_inches"])
    fig.set_layout_engine(None)  # laid out: savefig draws each file once
    paths = []
    for fmt in FORMATS:
        path = stem.with_name(f"{stem.name}.{fmt}")
        with _font_subsets_reused():
            fig.savefig(path, dpi=PNG_DPI, bbox_inches=bbox)
        paths.append(path)
    return paths


def _phi_max(log: RunLog, phi_max: float | Sequence[float] | None) -> np.ndarray | None:
    """Upper twist limit per rod [rad]: the argument, else the log's ``phi_max`` meta, else None."""
    if phi_max is None and log.meta.get("phi_max"):
        phi_max = float(log.meta["phi_max"])
    return None if phi_max is None else np.broadcast_to(np.asarray(phi_max, dtype=float), (2,))


def _error_mm(log: RunLog) -> np.ndarray:
    """‖p^d − p_ee‖ per tick [mm], clipped below at ERROR_FLOOR for the log axis."""
    return np.maximum(
        np.linalg.norm(log.chiee_des[:, :2] - log.chiee[:, :2], axis=1) * MM, ERROR_FLOOR
    )


def _error_axis(ax: Axes) -> None:
    """Log-scale ‖e‖ axis with its label."""
    ax.set_yscale("log")
    ax.set_ylabel(r"$\Vert p^d_\mathrm{ee} - p_\mathrm{ee} \Vert$ [mm]")


def _figure(rows: int, height: float, **kwargs: object) -> tuple[Figure, np.ndarray]:
    """A figure of ``rows`` panels over a shared time axis, laid out so that a legend fits below
    them."""
    return subplots(rows, 1, sharex=True, figsize=(7.5, height), layout="constrained", **kwargs)


def _finish(fig: Figure, axes: Sequence[Axes], title: str, t_end: float, columns: int = 4) -> None:
    """Time axis label and range, the title, and one legend of every labelled line below the
    panels."""
    axes[-1].set_xlabel("$t$ [s]")
    axes[-1].set_xlim(0.0, t_end)
    fig.suptitle(title)
    entries: dict[str, object] = {}
    for ax in axes:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(text, handle)
    fig.legend(
        list(entries.values()),
        list(entries),
        loc="outside lower center",
        ncols=min(columns, len(entries)),
    )


def _steps(log: RunLog) -> list[tuple[int, int]]:
    """Tick ranges of the setpoint steps of a step run ([] for a contour: more than MAX_STEPS
    setpoints)."""
    bounds = step_bounds(log.chiee_des[:, :2])
    return bounds if len(bounds) <= MAX_STEPS else []


def _step_window(log: RunLog, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """Tick mask of the window around the step of ticks [start, stop) and the time relative to its
    change.

    The window ends before the next step's first tick, so the next setpoint change is not drawn (nor
    scaled to).
    """
    tau = log.t - log.t[start]
    before_next = np.arange(len(log)) < stop
    return (tau >= STEP_WINDOW[0]) & (tau < STEP_WINDOW[1]) & before_next, tau


def _panel_grid(n: int, height: float = 1.9) -> tuple[Figure, list[Axes]]:
    """A grid of n panels, STEP_COLUMNS wide, spare panels removed."""
    cols = min(n, STEP_COLUMNS)
    rows = math.ceil(n / cols)
    fig, axes = subplots(
        rows,
        cols,
        figsize=(2.6 * cols, height * rows + 0.8),
        squeeze=False,
        sharex=True,
        layout="constrained",
    )
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.remove()
    return fig, flat[:n]


# --- one run
# --------------------------------------------------------------------------------------------------


def end_effector_figure(log: RunLog, label: RunLabel) -> Figure:
    """x_ee, y_ee vs reference over the run, and ‖e‖(t) on a log scale with the RMSE."""
    fig, axes = _figure(3, 6.6, height_ratios=(1, 1, 1.1))
    for k, ax in enumerate(axes[:2]):
        ax.plot(
            log.t, log.chiee[:, k] * MM, color="C0", label=r"measured $p_\mathrm{ee}$", gid="run:0"
        )
        ax.plot(log.t, log.chiee_des[:, k] * MM, label=r"reference $p^d_\mathrm{ee}$", **SETPOINT)
        ax.set_ylabel(f"{AXES_XY[k]} [mm]")
    axes[2].plot(log.t, _error_mm(log), color="C3", lw=0.8, label="tracking error", gid="run:0")
    axes[2].axhline(
        label.rmse * MM, color="k", ls=":", lw=1.0, label=f"RMSE {label.rmse * MM:.2f} mm"
    )
    _error_axis(axes[2])
    _finish(fig, axes, label.title("End-effector position"), log.t[-1])
    return fig


def steps_figure(log: RunLog, label: RunLabel) -> Figure | None:
    """One panel per step: p_ee − p^d_k (x, y) from 0.25 s before to 2 s after the change; None for
    contours."""
    bounds = _steps(log)
    if not bounds:
        return None
    fig, axes = _panel_grid(len(bounds))
    for i, (ax, (start, stop)) in enumerate(zip(axes, bounds)):
        window, tau = _step_window(log, start, stop)
        target = log.chiee_des[start, :2]
        for k, color in enumerate(("C0", "C1")):
            ax.plot(
                tau[window],
                (log.chiee[window, k] - target[k]) * MM,
                color=color,
                label=AXES_XY[k],
                gid="run:0",
            )
        for k in range(2):  # the reference steps from −Δ to 0 in each axis
            ref = (log.chiee_des[window, k] - target[k]) * MM
            # drawn from the right (steps-pre backwards = steps-post) so the x and y dashes coincide
            # on the 0 line
            ax.plot(
                tau[window][::-1],
                ref[::-1],
                label=r"$p^d_\mathrm{ee}$" if k == 0 else None,
                **{**SETPOINT, "drawstyle": "steps-pre"},
            )
        ax.set_title(f"step {i + 1} at {log.t[start]:.1f} s", fontsize=8)
        ax.set_xlim(*STEP_WINDOW)
    for ax in axes[-STEP_COLUMNS:]:
        ax.set_xlabel(r"$t - t_k$ [s]")
        ax.tick_params(labelbottom=True)
    for ax in axes[::STEP_COLUMNS]:
        ax.set_ylabel(r"$p_\mathrm{ee} - p^d_{\mathrm{ee},k}$ [mm]")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
    fig.suptitle(label.title("Step responses (first 2 s of each step)"))
    return fig


def path_figure(log: RunLog, label: RunLabel) -> Figure:
    """The x–y plane: measured path over the setpoints of a step run or the reference path of a
    contour."""
    fig, ax = subplots(figsize=(5.5, 5.5))
    ax.plot(
        log.chiee[:, 0] * MM,
        log.chiee[:, 1] * MM,
        color="C0",
        lw=0.8,
        label="measured",
        gid="run:0",
    )
    _draw_reference_path(ax, log)
    _path_axes(ax)
    ax.set_title(label.title("End-effector path"))
    return fig


def _draw_reference_path(ax: Axes, log: RunLog, color: str = "k", whose: str = "") -> None:
    """Setpoints as numbered crosses (step run) or the reference path dashed (contour), on top."""
    bounds = _steps(log)
    if bounds:
        points = np.array([log.chiee_des[a, :2] for a, _ in bounds]) * MM
        ax.plot(
            points[:, 0],
            points[:, 1],
            marker="x",
            ms=7,
            mew=1.6,
            ls="none",
            color=color,
            zorder=5,
            label=f"setpoints $p^d_\\mathrm{{ee}}${whose}",
            gid="reference",
        )
        for i, (x, y) in enumerate(points):
            ax.annotate(
                str(i + 1),
                (x, y),
                textcoords="offset points",
                xytext=(4, 4),
                fontsize=7,
                color=color,
            )
    else:
        ax.plot(
            log.chiee_des[:, 0] * MM,
            log.chiee_des[:, 1] * MM,
            label=f"reference $p^d_\\mathrm{{ee}}${whose}",
            **{**REFERENCE, "color": color},
        )


def _path_axes(ax: Axes) -> None:
    """Labels, equal scale, y downwards (the robot hangs), legend."""
    ax.set_xlabel(f"{AXES_XY[0]} [mm]")
    ax.set_ylabel(f"{AXES_XY[1]} [mm]")
    ax.invert_yaxis()
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="best")


def actuation_figure(
    log: RunLog, label: RunLabel, phi_max: float | Sequence[float] | None = None
) -> Figure:
    """φ₁, φ₂: command (saturated), measured, φ^ss (laws that have it) and the limits [0, φ_max]."""
    limits = _phi_max(log, phi_max)
    fig, axes = _figure(2, 5.2)
    for k, ax in enumerate(axes):
        ax.plot(
            log.t,
            log.phi_sat[:, k],
            color="C3",
            drawstyle="steps-post",
            label=r"command $\phi$ (saturated)",
            gid="run:0",
        )
        if log.phi_meas is not None:
            ax.plot(
                log.t,
                log.phi_meas[:, k],
                color="C0",
                lw=0.8,
                label=r"measured $\phi$",
                gid="measured",
            )
        if has_phi_ss(log):
            ax.plot(log.t, log.phi_ss[:, k], label=r"steady state $\phi^\mathrm{ss}$", **SETPOINT)
        if limits is not None:
            _draw_limits(ax, float(limits[k]))
        ax.set_ylabel(f"$\\phi_{k + 1}$ [rad]")
    _finish(fig, axes, label.title("Actuation"), log.t[-1])
    return fig


def _draw_limits(ax: Axes, phi_max: float) -> None:
    """The admissible band [0, φ_max] as two dash-dotted lines, with some room beyond."""
    ax.axhline(0.0, label=r"limits $[0, \phi_\mathrm{max}]$", gid="limit", **LIMIT)
    ax.axhline(phi_max, gid="limit", **LIMIT)
    ax.set_ylim(-0.08 * phi_max, 1.08 * phi_max)


def configuration_figure(log: RunLog, label: RunLabel) -> Figure:
    """Configuration q vs q^d over time."""
    names = (r"\kappa_\mathrm{be}", r"\sigma_\mathrm{sh}", r"\sigma_\mathrm{ax}")
    units = ("rad/m", "–", "–")
    fig, axes = _figure(3, 6.4)
    for k, ax in enumerate(axes):
        ax.plot(log.t, log.q[:, k], color="C1", label="measured $q$", gid="run:0")
        ax.plot(log.t, log.q_des[:, k], label="setpoint $q^d$", **SETPOINT)
        ax.set_ylabel(f"${names[k]}$ [{units[k]}]")
    _finish(fig, axes, label.title("Configuration"), log.t[-1])
    return fig


def collocated_figure(log: RunLog, label: RunLabel) -> Figure:
    """Collocated actuation coordinates ϑ₁, ϑ₂ vs ϑ^d over time."""
    fig, axes = _figure(2, 4.8)
    for k, ax in enumerate(axes):
        ax.plot(log.t, log.varphi[:, k], color="C2", label=r"measured $\vartheta$", gid="run:0")
        ax.plot(log.t, log.varphi_des[:, k], label=r"setpoint $\vartheta^d$", **SETPOINT)
        ax.set_ylabel(f"$\\vartheta_{k + 1}$ [N m/rad]")
    _finish(fig, axes, label.title("Collocated coordinates"), log.t[-1])
    return fig


def all_figures(
    log: RunLog,
    out_dir: Path,
    prefix: str = "",
    phi_max: float | Sequence[float] | None = None,
    contour: bool = False,
    rmse: float | None = None,
) -> list[Path]:
    """Write every figure of a run into ``out_dir`` as PDF and PNG; return the paths.

    ``phi_max`` [rad] (default: the log's ``phi_max`` meta) draws the actuation limits; ``rmse`` [m]
    (default: over the log) goes into the titles; ``contour`` draws no step figure even for few
    setpoints.
    """
    label = RunLabel.of(log, rmse)
    with matplotlib.rc_context(STYLE):
        figures = {
            "end_effector": end_effector_figure(log, label),
            "steps": None if contour else steps_figure(log, label),
            "path": path_figure(log, label),
            "actuation": actuation_figure(log, label, phi_max),
            "configuration": configuration_figure(log, label),
            "collocated": collocated_figure(log, label),
        }
        return [
            path
            for name, fig in figures.items()
            if fig is not None
            for path in save_all_formats(fig, out_dir / f"{prefix}{name}")
        ]


# --- several runs
# --------------------------------------------------------------------------------------------------


def _setpoints(log: RunLog) -> np.ndarray:
    """(t [s], x [m], y [m]) of every setpoint change of a run."""
    return np.array(
        [(log.t[a], *log.chiee_des[a, :2]) for a, _ in step_bounds(log.chiee_des[:, :2])]
    )


def _same_reference(a: RunLog, b: RunLog) -> bool:
    """Whether two runs tracked the same setpoints at the same times (within 50 ms and 10 µm: drawn
    as one)."""
    sa, sb = _setpoints(a), _setpoints(b)
    if sa.shape != sb.shape:
        return False
    return np.allclose(sa[:, 0], sb[:, 0], atol=0.05) and np.allclose(
        sa[:, 1:], sb[:, 1:], atol=1e-5
    )


def _references(logs: Sequence[RunLog], labels: Sequence[RunLabel]) -> list[tuple[int, str, str]]:
    """(run index, colour, legend suffix) of each distinct reference: one black one if all runs
    share it."""
    owners = [
        i for i, log in enumerate(logs) if not any(_same_reference(log, logs[j]) for j in range(i))
    ]
    if len(owners) == 1:
        return [(0, "k", "")]
    return [(i, f"C{i}", f" of {labels[i].law}, {labels[i].material}") for i in owners]


def overlay_end_effector_figure(logs: Sequence[RunLog], labels: Sequence[RunLabel]) -> Figure:
    """x_ee, y_ee of every run over the reference (each distinct one, in its run's colour), every
    run's ‖e‖(t)."""
    fig, axes = _figure(3, 7.0, height_ratios=(1, 1, 1.1))
    for i, (log, label) in enumerate(zip(logs, labels)):
        for k in range(2):
            axes[k].plot(
                log.t,
                log.chiee[:, k] * MM,
                color=f"C{i}",
                lw=0.8,
                label=label.short,
                gid=f"run:{i}",
            )
        axes[2].plot(log.t, _error_mm(log), color=f"C{i}", lw=0.7, gid=f"run:{i}")
    for i, color, whose in _references(logs, labels):
        for k in range(2):
            axes[k].plot(
                logs[i].t,
                logs[i].chiee_des[:, k] * MM,
                label=f"reference $p^d_\\mathrm{{ee}}${whose}",
                **{**SETPOINT, "color": color},
            )
    for k in range(2):
        axes[k].set_ylabel(f"{AXES_XY[k]} [mm]")
    _error_axis(axes[2])
    _finish(
        fig,
        axes,
        f"End-effector position, {len(logs)} runs",
        max(log.t[-1] for log in logs),
        columns=2,
    )
    return fig


def overlay_steps_figure(logs: Sequence[RunLog], labels: Sequence[RunLabel]) -> Figure | None:
    """Per step, every run's distance to its step's target ‖p_ee − p^d_k‖ (first 2 s), with the
    references."""
    bounds = [_steps(log) for log in logs]
    n = min(len(b) for b in bounds)
    if n == 0:
        return None
    fig, axes = _panel_grid(n)
    for i, (log, label, steps) in enumerate(zip(logs, labels, bounds)):
        for ax, (start, stop) in zip(axes, steps):
            window, tau = _step_window(log, start, stop)
            target = log.chiee_des[start, :2]
            distance = np.linalg.norm(log.chiee[window, :2] - target, axis=1) * MM
            ax.plot(tau[window], distance, color=f"C{i}", label=label.short, gid=f"run:{i}")
    references = _references(logs, labels)
    for i, color, whose in references:  # on top of the runs
        for ax, (start, stop) in zip(axes, bounds[i]):
            window, tau = _step_window(logs[i], start, stop)
            ref = (
                np.linalg.norm(logs[i].chiee_des[window, :2] - logs[i].chiee_des[start, :2], axis=1)
                * MM
            )
            ax.plot(tau[window], ref, label=f"reference{whose}", **{**SETPOINT, "color": color})
    for j, (ax, (start, _)) in enumerate(
        zip(axes, bounds[0])
    ):  # the time only where all runs share it
        ax.set_title(
            f"step {j + 1}" + (f" at {logs[0].t[start]:.1f} s" if len(references) == 1 else ""),
            fontsize=8,
        )
        ax.set_xlim(*STEP_WINDOW)
    for ax in axes[-STEP_COLUMNS:]:
        ax.set_xlabel(r"$t - t_k$ [s]")
        ax.tick_params(labelbottom=True)
    for ax in axes[::STEP_COLUMNS]:
        ax.set_ylabel(r"$\Vert p_\mathrm{ee} - p^d_{\mathrm{ee},k} \Vert$ [mm]")
    handles, texts = axes[0].get_legend_handles_labels()
    fig.legend(handles, texts, loc="outside lower center", ncols=min(2, len(texts)))
    fig.suptitle(f"Step responses (distance to the step's target), {len(logs)} runs")
    return fig


def overlay_path_figure(logs: Sequence[RunLog], labels: Sequence[RunLabel]) -> Figure:
    """Every run's path in the x–y plane over the setpoints or reference paths (each distinct
    one)."""
    points = np.concatenate(
        [np.concatenate([log.chiee[:, :2], log.chiee_des[:, :2]]) for log in logs]
    )
    # m; the plane's height for the width, legend below
    width, height = np.ptp(points, axis=0) + 1e-3
    fig_height = float(np.clip(5.5 * height / width, 2.0, 8.0)) + 0.8 + 0.22 * len(logs)
    fig, ax = subplots(figsize=(6.5, fig_height), layout="constrained")
    for i, (log, label) in enumerate(zip(logs, labels)):
        ax.plot(
            log.chiee[:, 0] * MM,
            log.chiee[:, 1] * MM,
            color=f"C{i}",
            lw=0.8,
            label=label.short,
            gid=f"run:{i}",
        )
    for i, color, whose in _references(logs, labels):
        _draw_reference_path(ax, logs[i], color, whose)
    _path_axes(ax)
    ax.get_legend().remove()  # below the plane instead: paths fill the axes
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=1)
    fig.suptitle(f"End-effector path, {len(logs)} runs")
    return fig


def overlay_actuation_figure(
    logs: Sequence[RunLog],
    labels: Sequence[RunLabel],
    phi_max: float | Sequence[float] | None = None,
) -> Figure:
    """Every run's commanded φ₁, φ₂ with the limits [0, φ_max]: each distinct φ_max in its run's
    colour."""
    limits = [_phi_max(log, phi_max) for log in logs]
    owners = [
        i
        for i, lim in enumerate(limits)
        if lim is not None
        and not any(limits[j] is not None and np.allclose(limits[j], lim) for j in range(i))
    ]
    fig, axes = _figure(2, 5.6)
    for i, (log, label) in enumerate(zip(logs, labels)):
        for k, ax in enumerate(axes):
            ax.plot(
                log.t,
                log.phi_sat[:, k],
                color=f"C{i}",
                drawstyle="steps-post",
                lw=0.8,
                label=label.short,
                gid=f"run:{i}",
            )
    for k, ax in enumerate(axes):
        if len(owners) == 1:
            _draw_limits(ax, float(limits[owners[0]][k]))
        elif owners:
            ax.axhline(0.0, gid="limit", **LIMIT)
            for i in owners:
                ax.axhline(
                    float(limits[i][k]),
                    label=f"$\\phi_\\mathrm{{max}}$ of {labels[i].material}",
                    gid="limit",
                    **{**LIMIT, "color": f"C{i}"},
                )
            top = max(float(limits[i][k]) for i in owners)
            ax.set_ylim(-0.08 * top, 1.08 * top)
        ax.set_ylabel(f"$\\phi_{k + 1}$ command [rad]")
    _finish(
        fig,
        axes,
        f"Actuation (commands), {len(logs)} runs",
        max(log.t[-1] for log in logs),
        columns=2,
    )
    return fig


def overlay_figures(
    logs: Sequence[RunLog],
    out_dir: Path,
    rmses: Sequence[float | None] | None = None,
    phi_max: float | Sequence[float] | None = None,
) -> list[Path]:
    """Write the overlay figures of several runs into ``out_dir`` (``overlay_<name>.pdf/.png``);
    return the paths."""
    if len(logs) < 2:
        raise ValueError(f"an overlay needs at least 2 runs, got {len(logs)}")
    labels = [RunLabel.of(log, r) for log, r in zip(logs, rmses or [None] * len(logs))]
    with matplotlib.rc_context(STYLE):
        figures = {
            "end_effector": overlay_end_effector_figure(logs, labels),
            "steps": overlay_steps_figure(logs, labels),
            "path": overlay_path_figure(logs, labels),
            "actuation": overlay_actuation_figure(logs, labels, phi_max),
        }
        return [
            path
            for name, fig in figures.items()
            if fig is not None
            for path in save_all_formats(fig, out_dir / f"overlay_{name}")
        ]

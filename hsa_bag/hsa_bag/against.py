"""``hsa_analyze RUN --against REFERENCE``: a run overlaid on a reference run, step by step (no ROS
installation).

RUN and REFERENCE are each a bag, an NPZ RunLog (``hsa_experiment``'s ``log.npz``) or the name of a
packaged real run of the paper (``hsa_core.runs.reference``, e.g. 20230925_093236). A recorded
or simulated run is its tracking ticks (t = 0 at the first, as :func:`hsa_bag.bagrun.load_run`
reads it); a real run its 100 Hz grid; each ends ``duration`` after its t = 0 (110 s by default,
experiments.md §4). Every number is :mod:`hsa_core.analysis.sim_to_real` (each step aligned at its
own instant, steps 1–10): D and D per step, rise time, overshoot, end error and end peak-to-peak per
step of either run, each run's RMSE. Written to the output directory: ``against.txt`` (the table
also printed), ``against.json`` (SI units) and the figures ``figures/against_xy`` (x and y over
time, run, reference and setpoints, each run's step instants marked) and ``figures/against_steps``
(‖p^d − p‖ of every step, the two runs aligned at their own step instants), each as PDF and PNG.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hsa_bag.bagio import BagError
from hsa_bag.bagrun import FIGURES, STEP_RUN_DURATION, TOPIC, load_run, run_name
from hsa_core.analysis import sim_to_real
from hsa_core.analysis.plotting import save_all_formats, subplots
from hsa_core.analysis.sim_to_real import StepRun, StepTable
from hsa_core.runs import reference


@dataclass(frozen=True)
class Source:
    """A run to compare: its name, what it is (``real run``, ``bag``, ``log``) and its samples."""

    name: str
    kind: str
    run: StepRun


def load_source(text: str, duration: float = STEP_RUN_DURATION, topic: str = TOPIC) -> Source:
    """The run ``text`` names (module docstring); BagError (one line) for an unknown name or an
    unreadable file."""
    path = Path(text)
    if not path.exists():
        if text in reference.run_names():
            real = reference.load_run(text)
            return Source(text, "real run", StepRun(real.t, real.p, real.p_des, duration))
        raise BagError(
            f"{text}: no such file, and not a real run of the paper (known: "
            f"{', '.join(reference.run_names())})"
        )
    log = load_run(path, topic)
    try:
        run = StepRun.of_log(log, duration)
    except ValueError as exc:
        raise BagError(f"{path}: cannot be compared: {exc}") from None
    return Source(run_name(path), "log" if path.suffix == ".npz" else "bag", run)


@dataclass(frozen=True)
class Against:
    """The comparison of a run with a reference: the run-level table and the per-step one."""

    run: Source
    ref: Source
    summary: sim_to_real.Comparison
    steps: StepTable

    def text(self) -> str:
        """The table (mm, s) as printed."""
        s, c = self.steps, self.summary
        lines = [
            f"{self.run.name} ({self.run.kind}) against {self.ref.name} ({self.ref.kind}), steps "
            f"{s.steps[0]}-{s.steps[-1]} each aligned at its own instant; run / reference",
            f"D = {c.deviation * 1e3:.2f} mm, RMSE {c.rmse[0] * 1e3:.2f} / {c.rmse[1] * 1e3:.2f} "
            f"mm, median relative difference of rise time {c.rise_time_difference * 100:.0f} %, of "
            f"response time {c.response_time_difference * 100:.0f} %",
            "",
            f"{'step':>4} {'start [s]':>13} {'D [mm]':>7} {'rise time [s]':>13} "
            f"{'overshoot [mm]':>15} {'end error [mm]':>15} {'x p2p [mm]':>13} {'y p2p [mm]':>13}",
        ]
        for i, k in enumerate(s.steps):

            def pair(
                values: tuple[np.ndarray, np.ndarray], scale: float, axis: int | None = None
            ) -> str:
                a, b = (v[i] if axis is None else v[i, axis] for v in values)
                return f"{a * scale:.2f}/{b * scale:.2f}"

            lines.append(
                f"{k:>4} {pair(s.start, 1.0):>13} {s.deviation[i] * 1e3:7.2f} "
                f"{pair(s.rise_time, 1.0):>13} "
                f"{pair(s.overshoot, 1e3):>15} {pair(s.end_error, 1e3):>15} "
                f"{pair(s.peak_to_peak, 1e3, 0):>13} {pair(s.peak_to_peak, 1e3, 1):>13}"
            )
        return "\n".join(lines) + "\n"

    def as_dict(self) -> dict[str, object]:
        """The comparison for JSON (SI units, NaN as null)."""
        c = self.summary
        return {
            "run": {"name": self.run.name, "kind": self.run.kind},
            "reference": {"name": self.ref.name, "kind": self.ref.kind},
            "units": "m, s",
            "deviation": c.deviation,
            "rmse": {"run": c.rmse[0], "reference": c.rmse[1]},
            "x_peak_to_peak_max": {"run": c.x_peak_to_peak[0], "reference": c.x_peak_to_peak[1]},
            "end_error_median": {"run": c.end_error[0], "reference": c.end_error[1]},
            "rise_time_median_relative_difference": _num(c.rise_time_difference),
            "response_time_median_relative_difference": _num(c.response_time_difference),
            "steps": self.steps.rows(),
        }


def _num(value: float) -> float | None:
    """A JSON number (NaN as null)."""
    return None if np.isnan(value) else float(value)


def compare(run: Source, ref: Source) -> Against:
    """Both tables of ``run`` against ``ref``; BagError (one line) if either lacks steps 1–10 or
    ends too early."""
    try:
        return Against(
            run,
            ref,
            sim_to_real.compare(run.run, ref.run),
            sim_to_real.step_table(run.run, ref.run),
        )
    except ValueError as exc:
        raise BagError(f"{run.name} against {ref.name} cannot be compared: {exc}") from None


def write(result: Against, out: Path) -> list[Path]:
    """against.txt, against.json and the figures (PDF, PNG) in ``out``; the files written."""
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "against.txt", out / "against.json"]
    files[0].write_text(result.text(), encoding="utf8")
    files[1].write_text(json.dumps(result.as_dict(), indent=1) + "\n", encoding="utf8")
    return files + xy_figure(result, out / FIGURES) + steps_figure(result, out / FIGURES)


RUN_STYLE = {"color": "tab:blue", "lw": 1.0}
REF_STYLE = {"color": "tab:orange", "lw": 1.0}
SETPOINT_STYLE = {"color": "k", "lw": 0.8, "ls": "--"}


def xy_figure(result: Against, folder: Path) -> list[Path]:
    """x and y [mm] over time: run, reference and the run's setpoints; each run's step instants as
    thin lines."""
    fig, axes = subplots(2, 1, sharex=True, figsize=(7.5, 4.6), layout="constrained")
    run, ref = result.run.run, result.ref.run
    for axis, (ax, label) in enumerate(zip(axes, ("x", "y"))):
        keep = ref.t < ref.end
        ax.plot(
            ref.t[keep],
            ref.p[keep, axis] * 1e3,
            label=f"{result.ref.name} ({result.ref.kind})",
            **REF_STYLE,
        )
        keep = run.t < run.end
        ax.plot(
            run.t[keep],
            run.p[keep, axis] * 1e3,
            label=f"{result.run.name} ({result.run.kind})",
            **RUN_STYLE,
        )
        ax.step(
            run.t[keep],
            run.p_des[keep, axis] * 1e3,
            where="post",
            label="setpoint",
            **SETPOINT_STYLE,
        )
        for start in run.step_starts:
            ax.axvline(start, color="tab:blue", alpha=0.3, lw=0.6, zorder=0)
        for start in ref.step_starts:
            ax.axvline(start, color="tab:orange", alpha=0.4, lw=0.6, ls=":", zorder=0)
        ax.set_ylabel(f"${label}_\\mathrm{{ee}}$ [mm]")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("$t$ [s]")
    axes[-1].set_xlim(0.0, max(run.end, ref.end))
    fig.suptitle(
        f"{result.run.name} against {result.ref.name}: D = {result.summary.deviation * 1e3:.2f} mm"
    )
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=3)
    return save_all_formats(fig, folder / "against_xy")


def steps_figure(result: Against, folder: Path) -> list[Path]:
    """‖p^d − p‖ [mm] of every compared step over the aligned window, run and reference, D of each
    step."""
    table = result.steps
    n = len(table.steps)
    cols = 5
    fig, axes = subplots(
        -(-n // cols),
        cols,
        sharex=True,
        sharey=True,
        figsize=(10.0, 4.4),
        layout="constrained",
        squeeze=False,
    )
    offsets = np.arange(round(sim_to_real.HORIZON / sim_to_real.GRID)) * sim_to_real.GRID
    errors = []
    for source in (result.run, result.ref):
        responses = sim_to_real.aligned_responses(source.run, table.steps)
        targets = [
            source.run.setpoint_at(start) for start, _ in source.run.step_bounds(table.steps)
        ]
        errors.append(
            [np.linalg.norm(p - target, axis=1) * 1e3 for p, target in zip(responses, targets)]
        )
    for i, (ax, k) in enumerate(zip(axes.flat, table.steps)):
        ax.plot(offsets, errors[1][i], label=result.ref.name, **REF_STYLE)
        ax.plot(offsets, errors[0][i], label=result.run.name, **RUN_STYLE)
        ax.set_title(f"step {k}: D = {table.deviation[i] * 1e3:.2f} mm", fontsize=9)
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("$t - t_k$ [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$\Vert p^d - p \Vert$ [mm]")
    fig.suptitle(
        f"Steps aligned at their own instants: {result.run.name} against {result.ref.name}"
    )
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=2)
    return save_all_formats(fig, folder / "against_steps")

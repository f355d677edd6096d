"""Offline analysis of recorded runs: bag → RunLog (:mod:`hsa_bag.bagrun`) → metrics tables,
figures, CSV/NPZ (no ROS installation needed).

``hsa_analyze RUN [RUN ...] [--out DIR] [--duration S] [--csv] [--npz] [--topic T] [--contour]
[--phi-max RAD] [--name N]``: a RUN is a bag (directory or .mcap file) or the NPZ log of an offline
experiment (``hsa_experiment``'s ``log.npz``, or a ``run.npz`` written here). For each run it prints
the run summary and the per-step table (``hsa_core.analysis.metrics``) and writes into its directory
(DIR for one run, default ``out/analysis/<name>``; DIR/<name> for several, default DIR
``out/analysis/overlay``): ``metrics.txt``, with ``--csv``/``--npz`` the RunLog as
``run.csv``/``run.npz``, and the figures of ``hsa_core.analysis.plotting`` (PDF and PNG) under
``figures/``. With several runs, DIR also gets the summary table of all runs in ``metrics.txt`` and
the overlay figures in ``figures/``. The step figure is left out, and the Cartesian path drawn as a
line, for contour runs: a trajectory longer than ``CONTOUR_MIN_POINTS`` setpoints, or ``--contour``.
Trimming: ``--duration S`` keeps 0 ≤ t < S; by default 110 s for step runs (experiments.md §4) and
the whole run for contours; ``--duration 0`` keeps everything, and so does a duration beyond the
last tick (the last step then ends one tick period after its last tick). A bad bag (truncated file,
missing metadata, topic or type definition, no tracking tick) exits with code 2 and a message naming
what is missing; so does a bad argument, in one line. ``--against REFERENCE``: one run compared step
by step with a reference run (:mod:`hsa_bag.against`). A message that does not decode is no reason
to lose the run: it is skipped, and one line per topic on stderr says how many were. Long bags show
a progress bar (tqdm, on a terminal).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from hsa_bag import against
from hsa_bag.bagio import BagError
from hsa_bag.bagrun import (
    FIGURES,
    STEP_RUN_DURATION,
    TOPIC,
    is_contour,
    load_run,
    run_name,
    skipped_messages,
)
from hsa_core import cli
from hsa_core.analysis.metrics import RunMetrics, evaluate_run, format_steps, format_summary
from hsa_core.analysis.plotting import all_figures, overlay_figures
from hsa_core.jaxsetup import configure_jax
from hsa_core.runs.runlog import RunLog


@dataclass(frozen=True)
class Analysis:
    """Result of :func:`analyze`: the (trimmed) log, its metrics, the tables as text and the files
    written."""

    log: RunLog
    metrics: RunMetrics
    report: str
    files: list[Path]


def analyze(
    path: Path,
    out: Path,
    *,
    topic: str = TOPIC,
    duration: float | None = None,
    contour: bool | None = None,
    csv: bool = False,
    npz: bool = False,
    phi_max: float | None = None,
    name: str | None = None,
    progress: bool = False,
) -> Analysis:
    """Metrics, exports (in ``out``) and figures (in ``out/figures``) of one run (a bag or an NPZ
    RunLog).

    Defaults of duration and contour: module docstring.
    """
    log = load_run(path, topic, progress)
    contour = is_contour(log) if contour is None else contour
    if duration is None:
        duration = None if contour else STEP_RUN_DURATION
    if duration is not None and not 0.0 < duration <= log.t[-1]:
        # nothing to trim: the last step then ends one tick period after the last tick
        duration = None
    name = name or run_name(path)
    try:
        metrics = evaluate_run(
            log.t, log.chiee_des[:, :2], log.chiee[:, :2], log.saturated, duration, name
        )
    except ValueError as exc:
        raise BagError(f"{path}: topic {topic} cannot be evaluated: {exc}") from exc
    if duration is not None:
        log = log.trimmed(duration)
    out.mkdir(parents=True, exist_ok=True)
    report = f"{format_summary([metrics])}\n\n{format_steps(metrics)}\n"
    files = [out / "metrics.txt"]
    files[0].write_text(report, encoding="utf8")
    if csv:
        files.append(log.save_csv(out / "run.csv"))
    if npz:
        files.append(log.save_npz(out / "run.npz"))
    files += all_figures(log, out / FIGURES, phi_max=phi_max, contour=contour, rmse=metrics.rmse)
    return Analysis(log, metrics, report, files)


def overlay(results: Sequence[Analysis], out: Path, phi_max: float | None = None) -> list[Path]:
    """The summary table of several analysed runs (``out/metrics.txt``) and their overlay figures
    (``out/figures``)."""
    out.mkdir(parents=True, exist_ok=True)
    table = out / "metrics.txt"
    table.write_text(format_summary([r.metrics for r in results]) + "\n", encoding="utf8")
    logs = [r.log for r in results]
    return [
        table,
        *overlay_figures(logs, out / FIGURES, [r.metrics.rmse for r in results], phi_max),
    ]


def _unique_names(paths: Sequence[Path]) -> list[str]:
    """Run names of ``paths``, made distinct with a suffix where two runs would share one."""
    names: list[str] = []
    for path in paths:
        base = run_name(path)
        name, k = base, 2
        while name in names:
            name, k = f"{base}_{k}", k + 1
        names.append(name)
    return names


def main(argv: list[str] | None = None) -> int:
    """Console script ``hsa_analyze``."""
    configure_jax()
    parser = cli.ArgumentParser(prog="hsa_analyze", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "runs",
        type=Path,
        nargs="+",
        metavar="RUN",
        help="rosbag2 directory, .mcap file, or NPZ RunLog (hsa_experiment's log.npz); "
        "several runs are also drawn over each other",
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="output directory (default out/analysis/<name>, several runs out/analysis/overlay)",
    )
    parser.add_argument(
        "--duration",
        type=cli.non_negative,
        help="keep 0 <= t < S [s]; default 110 for step runs, all for contours; 0 = all",
    )
    parser.add_argument(
        "--csv",
        action="store_true",
        help="also write run.csv (one row per tick, units in the header)",
    )
    parser.add_argument(
        "--npz", action="store_true", help="also write run.npz (one array per field)"
    )
    parser.add_argument("--topic", default=TOPIC, help=f"ControllerInfo topic (default {TOPIC})")
    parser.add_argument(
        "--contour",
        action="store_true",
        default=None,
        help="a contour run: no step figure, the reference path drawn as a line",
    )
    parser.add_argument(
        "--phi-max",
        type=cli.positive,
        help="[rad] actuation limit drawn in the actuation figures (default: the material's)",
    )
    parser.add_argument(
        "--name", help="run name in the tables (one run only; default the bag name)"
    )
    parser.add_argument(
        "--against",
        metavar="REFERENCE",
        help=(
            "compare the RUN step by step with REFERENCE (a bag, an NPZ RunLog or a real run of "
            "the paper, e.g. 20230925_093236; RUN may be one too): table, against.json, figures "
            "(default --out out/analysis/<run>_against_<reference>)"
        ),
    )
    args = parser.parse_args(argv)
    if args.against is not None:
        return _against(parser, args)
    missing = [str(p) for p in args.runs if not p.exists()]
    if missing:
        parser.error("; ".join(f"{p} does not exist" for p in missing))
    several = len(args.runs) > 1
    if several and args.name:
        parser.error("--name names one run; several runs are named after their paths")
    names = [args.name] if args.name else _unique_names(args.runs)
    out = args.out or Path("out", "analysis", "overlay" if several else names[0])
    results = []
    try:
        for path, name in zip(args.runs, names):
            result = analyze(
                path,
                out / name if several else out,
                topic=args.topic,
                duration=args.duration,
                contour=args.contour,
                csv=args.csv,
                npz=args.npz,
                phi_max=args.phi_max,
                name=name,
                progress=True,
            )
            for skipped_topic, count in skipped_messages(result.log).items():
                print(
                    f"hsa_analyze: {path}: skipped {count} undecodable message(s) on "
                    f"{skipped_topic}",
                    file=sys.stderr,
                )
            print(result.report)
            results.append(result)
        files = [f for r in results for f in r.files] + (
            overlay(results, out, args.phi_max) if several else []
        )
    except BagError as exc:
        print(f"hsa_analyze: {exc}", file=sys.stderr)
        return 2
    if several:
        print(format_summary([r.metrics for r in results]))
    print(f"wrote {len(files)} files to {out}")
    return 0


def _against(parser: cli.ArgumentParser, args: argparse.Namespace) -> int:
    """``--against``: one run compared with a reference (hsa_bag.against); exit 2 with one line on a
    bad input."""
    if len(args.runs) != 1:
        parser.error(f"--against compares one RUN with the reference, got {len(args.runs)}")
    duration = args.duration or STEP_RUN_DURATION
    try:
        result = against.compare(
            against.load_source(str(args.runs[0]), duration, args.topic),
            against.load_source(args.against, duration, args.topic),
        )
        out = args.out or Path("out", "analysis", f"{result.run.name}_against_{result.ref.name}")
        files = against.write(result, out)
    except BagError as exc:
        print(f"hsa_analyze: {exc}", file=sys.stderr)
        return 2
    print(result.text())
    print(f"wrote {len(files)} files to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

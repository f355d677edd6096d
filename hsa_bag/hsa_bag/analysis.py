"""Offline analysis of recorded runs: bag → RunLog → metrics tables, figures, CSV/NPZ (no ROS
installation needed).

:func:`runlog_from_bag` turns the controller's ``hsa_msgs/ControllerInfo`` messages into an
``hsa_core`` RunLog,
decoded with the definition stored in the bag:

* only ticks in ``STATE_TRACKING`` count: waiting, hold-stale and stopped ticks send no new command
  and are not part of the tracked run;
* ``t`` = ``header.stamp`` (the controller tick time) minus the stamp of the first tracking tick
  [s]; ticks are ordered by stamp, and a tick whose stamp repeats an earlier one is dropped;
* fields: chiee, chiee_des (x, y, theta), q, q_des (kappa_be, sigma_sh, sigma_ax), varphi,
  varphi_des, phi_ss, e_int, saturated as named; ``phi_des_unsat`` → ``phi_unsat``, ``phi_des_sat``
  → ``phi_sat``;
* ``phi_meas``: when the bag has ``/hsa/phi_present`` (hsa_msgs/PlanarActuation, the driver's
  measured twist), the newest measurement whose header stamp is at or before each tick (NaN before
  the first one);
* ``meta``: bag, topic, controller, ``ee_integral`` (``true`` when the EE-integral state ``z_ee``
  was ever non-zero), ``trajectory_length`` (the largest ``Setpoint.trajectory_length`` seen), and
  where the bag tells: ``material`` (the kinematics node's diagnostics) and ``setup`` (``sim`` if a
  ``sim_node`` reported diagnostics, ``robot`` if the Dynamixel driver did without it); the bag's
  ``custom_data`` keys ``material`` and ``setup`` take precedence; ``phi_max`` [rad] of the
  material's parameter file; ``skipped <topic>``: how many messages of that topic did not decode
  (malformed CDR that a recorder stored raw) and were left out.

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
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hsa_bag.bagio import Bag, BagError, stamp_ns
from hsa_bag.storage import read_metadata
from hsa_core.analysis.metrics import RunMetrics, evaluate_run, format_steps, format_summary
from hsa_core.analysis.plotting import all_figures, overlay_figures
from hsa_core.analysis.runlog import RunLog
from hsa_core.apps import cli
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.params import ParameterError, load_params

TOPIC = "/hsa/controller_info"
CONTROLLER_INFO = "hsa_msgs/msg/ControllerInfo"
PHI_TOPIC = "/hsa/phi_present"
PLANAR_ACTUATION = "hsa_msgs/msg/PlanarActuation"
DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
STEP_RUN_DURATION = 110.0  # s, experiments.md §4
CONTOUR_MIN_POINTS = 20  # a setpoint trajectory longer than this is a contour, not a step list
PROGRESS_MIN_MESSAGES = 20_000  # about 8 min of 40 Hz ticks
FIGURES = "figures"  # subdirectory of a run's output that holds its figures
GENERIC_STEMS = (
    "log",
    "run",
    "bag",
)  # file or directory names that say nothing: the run is named by its parent
SKIPPED = "skipped "  # RunLog meta key prefix: undecodable messages left out, per topic


def _pose(p: object) -> tuple[float, float, float]:
    """PlanarPose → (x, y, theta)."""
    return (p.x, p.y, p.theta)  # type: ignore[attr-defined]


def _config(q: object) -> tuple[float, float, float]:
    """CsConfiguration → (kappa_be, sigma_sh, sigma_ax)."""
    return (q.kappa_be, q.sigma_sh, q.sigma_ax)  # type: ignore[attr-defined]


def _measured_phi(bag: Bag) -> tuple[np.ndarray, np.ndarray] | None:
    """(stamps [ns], φ (M, 2) [rad]) of ``/hsa/phi_present`` in stamp order; None if the bag lacks
    the topic."""
    info = bag.topics.get(PHI_TOPIC)
    if info is None or info.msgtype != PLANAR_ACTUATION or info.count == 0:
        return None
    samples = sorted(
        (stamp_ns(msg.header.stamp), tuple(msg.phi)) for _, msg in bag.decoded(PHI_TOPIC)
    )
    if not samples:
        return None
    return np.array([s for s, _ in samples], dtype=np.int64), np.array(
        [p for _, p in samples], dtype=np.float64
    )


def _setup_meta(bag: Bag) -> dict[str, str]:
    """``material`` and ``setup`` as the bag tells them: its custom_data, else the nodes'
    diagnostics."""
    meta: dict[str, str] = {}
    info = bag.topics.get(DIAGNOSTICS_TOPIC)
    if info is not None and info.msgtype == DIAGNOSTIC_ARRAY:
        nodes: set[str] = set()
        for _, msg in bag.decoded(DIAGNOSTICS_TOPIC):
            for status in msg.status:
                node = status.name.partition(":")[0]
                nodes.add(node)
                if node == "kinematics_node" and "material" not in meta:
                    meta.update({kv.key: kv.value for kv in status.values if kv.key == "material"})
        if "sim_node" in nodes:
            meta["setup"] = "sim"
        elif "dynamixel_driver" in nodes:
            meta["setup"] = "robot"
    if bag.path.is_dir():
        custom = read_metadata(bag.path).get("custom_data") or {}
        meta.update({k: str(custom[k]) for k in ("material", "setup") if k in custom})
    return meta


def _phi_max_meta(material: str) -> dict[str, str]:
    """``phi_max`` [rad] of the material's parameter file (the largest rod limit), or nothing if
    unknown."""
    try:
        return {"phi_max": str(float(np.max(load_params(material).phi_limit.box[1])))}
    except (ParameterError, OSError, ValueError):
        return {}


def runlog_from_bag(path: Path | str, topic: str = TOPIC, progress: bool = False) -> RunLog:
    """The tracking ticks of ``topic`` in bag ``path`` as a RunLog (see the module docstring);
    BagError if unusable."""
    with Bag(path) as bag:
        info = bag.topic(topic)
        if info.msgtype != CONTROLLER_INFO:
            raise BagError(
                f"{bag.path}: topic {topic} has type {info.msgtype}, expected {CONTROLLER_INFO}"
            )
        store = bag.typestore(topic)
        tracking = store.types[CONTROLLER_INFO].STATE_TRACKING
        rows: dict[int, tuple] = {}
        controllers: set[str] = set()
        trajectory_length = 0
        ee_integral = False
        show = progress and info.count >= PROGRESS_MIN_MESSAGES
        for _, msg in tqdm(
            bag.decoded(topic), total=info.count, unit="msg", disable=None if show else True
        ):
            if msg.state != tracking:
                continue
            rows.setdefault(
                stamp_ns(msg.header.stamp),
                (
                    _pose(msg.chiee),
                    _pose(msg.chiee_des),
                    _config(msg.q),
                    _config(msg.q_des),
                    msg.varphi,
                    msg.varphi_des,
                    msg.phi_ss,
                    msg.phi_des_unsat,
                    msg.phi_des_sat,
                    msg.e_int,
                    msg.saturated,
                ),
            )
            controllers.add(msg.controller)
            trajectory_length = max(trajectory_length, msg.setpoint.trajectory_length)
            ee_integral = ee_integral or bool(np.any(np.asarray(msg.z_ee) != 0.0))
        measured = _measured_phi(bag)
        setup = _setup_meta(bag)
        skipped = dict(bag.skipped)
    if len(rows) < 2:
        undecodable = f", {skipped[topic]} of them undecodable," if topic in skipped else ""
        raise BagError(
            f"{path}: topic {topic} has {info.count} messages{undecodable} but {len(rows)} tick(s) "
            "in STATE_TRACKING "
            "(at least 2 are needed)"
        )
    stamps = np.array(sorted(rows), dtype=np.int64)
    columns = list(zip(*(rows[s] for s in stamps)))
    names = (
        "chiee",
        "chiee_des",
        "q",
        "q_des",
        "varphi",
        "varphi_des",
        "phi_ss",
        "phi_unsat",
        "phi_sat",
        "e_int",
    )
    arrays = {name: np.array(col, dtype=np.float64) for name, col in zip(names, columns)}
    phi_meas = None
    if measured is not None:
        newest = (
            np.searchsorted(measured[0], stamps, side="right") - 1
        )  # newest measurement at or before each tick
        phi_meas = np.where((newest >= 0)[:, None], measured[1][np.maximum(newest, 0)], np.nan)
    meta = {
        "bag": str(path),
        "topic": topic,
        "controller": ",".join(sorted(controllers)),
        "ee_integral": str(ee_integral).lower(),
        "trajectory_length": str(trajectory_length),
        **setup,
        **{f"{SKIPPED}{name}": str(count) for name, count in sorted(skipped.items())},
    }
    if "material" in meta:
        meta.update(_phi_max_meta(meta["material"]))
    return RunLog(
        t=(stamps - stamps[0]) * 1e-9,
        saturated=np.array(columns[-1], dtype=bool),
        phi_meas=phi_meas,
        meta=meta,
        **arrays,
    )


def load_run(path: Path | str, topic: str = TOPIC, progress: bool = False) -> RunLog:
    """A run from a bag, or from an NPZ RunLog (an offline experiment's ``log.npz``, or a
    ``run.npz``)."""
    path = Path(path)
    if path.suffix != ".npz":
        return runlog_from_bag(path, topic, progress)
    try:
        return RunLog.load_npz(path)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise BagError(f"{path}: not a RunLog NPZ file ({exc})") from exc


def skipped_messages(log: RunLog) -> dict[str, int]:
    """Topic → how many of its messages did not decode and were left out of the run (from the
    RunLog's meta)."""
    return {
        key[len(SKIPPED) :]: int(value)
        for key, value in log.meta.items()
        if key.startswith(SKIPPED)
    }


def run_name(path: Path | str) -> str:
    """A run's name from its path: the bag or file name, or its parent's when that says nothing
    (log.npz, bag/)."""
    path = Path(path).resolve()
    return path.parent.name if path.stem in GENERIC_STEMS and path.parent.name else path.stem


def is_contour(log: RunLog) -> bool:
    """Whether the run tracked a contour: more than CONTOUR_MIN_POINTS setpoints (from meta, else
    counted)."""
    if "trajectory_length" in log.meta:
        return int(log.meta["trajectory_length"]) > CONTOUR_MIN_POINTS
    changes = np.count_nonzero(np.any(np.diff(log.chiee_des[:, :2], axis=0) != 0.0, axis=1))
    return changes + 1 > CONTOUR_MIN_POINTS


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
        duration = (
            None  # nothing to trim: the last step then ends one tick period after the last tick
        )
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
            "the "
            "paper, e.g. 20230925_093236; RUN may be one too): table, against.json, figures "
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
    from hsa_bag import against  # it imports this module

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

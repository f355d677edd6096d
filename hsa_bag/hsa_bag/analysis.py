"""Offline analysis of a recorded run: bag → RunLog → metrics tables, figures, CSV/NPZ (no ROS installation needed).

:func:`runlog_from_bag` turns the controller's ``hsa_msgs/ControllerInfo`` messages into an ``hsa_core`` RunLog,
decoded with the definition stored in the bag:

* only ticks in ``STATE_TRACKING`` count: waiting, hold-stale and stopped ticks send no new command and are not part
  of the tracked run;
* ``t`` = ``header.stamp`` (the controller tick time) minus the stamp of the first tracking tick [s]; ticks are
  ordered by stamp, and a tick whose stamp repeats an earlier one is dropped;
* fields: chiee, chiee_des (x, y, theta), q, q_des (kappa_be, sigma_sh, sigma_ax), varphi, varphi_des, phi_ss,
  e_int, saturated as named; ``phi_des_unsat`` → ``phi_unsat``, ``phi_des_sat`` → ``phi_sat``;
* ``meta``: bag, topic, controller, and ``trajectory_length`` (the largest ``Setpoint.trajectory_length`` seen).

``hsa_analyze BAG [--out DIR] [--duration S] [--csv] [--npz] [--topic T] [--contour] [--phi-max RAD] [--name N]``
prints the run summary and the per-step table (``hsa_core.metrics``), writes them to ``metrics.txt`` with the PNG
figures of ``hsa_core.plotting`` into DIR (default ``out/analysis/<bag name>``), and with ``--csv``/``--npz`` the
RunLog as ``run.csv``/``run.npz``. The Cartesian path figure is drawn for contour runs: a trajectory longer than
``CONTOUR_MIN_POINTS`` setpoints, or ``--contour``. Trimming: ``--duration S`` keeps 0 ≤ t < S; by default 110 s for
step runs (experiments.md §4) and the whole run for contours; ``--duration 0`` keeps everything, and so does a
duration beyond the last tick (the last step then ends one tick period after its last tick, not at S). A bad bag
(truncated file, missing metadata, topic or type definition, no tracking tick) exits with code 2 and a message
naming what is missing. Long bags show a progress bar (tqdm, on a terminal).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hsa_bag.bagio import Bag, BagError
from hsa_core import cli
from hsa_core.metrics import RunMetrics, evaluate_run, format_steps, format_summary
from hsa_core.plotting import all_figures
from hsa_core.runlog import RunLog

TOPIC = "/hsa/controller_info"
CONTROLLER_INFO = "hsa_msgs/msg/ControllerInfo"
STEP_RUN_DURATION = 110.0  # s, experiments.md §4
CONTOUR_MIN_POINTS = 20  # a setpoint trajectory longer than this is a contour, not a step list
PROGRESS_MIN_MESSAGES = 20_000  # about 8 min of 40 Hz ticks


def _pose(p: object) -> tuple[float, float, float]:
    """PlanarPose → (x, y, theta)."""
    return (p.x, p.y, p.theta)  # type: ignore[attr-defined]


def _config(q: object) -> tuple[float, float, float]:
    """CsConfiguration → (kappa_be, sigma_sh, sigma_ax)."""
    return (q.kappa_be, q.sigma_sh, q.sigma_ax)  # type: ignore[attr-defined]


def runlog_from_bag(path: Path | str, topic: str = TOPIC, progress: bool = False) -> RunLog:
    """The tracking ticks of ``topic`` in bag ``path`` as a RunLog (see the module docstring); BagError if unusable."""
    with Bag(path) as bag:
        info = bag.topic(topic)
        if info.msgtype != CONTROLLER_INFO:
            raise BagError(f"{bag.path}: topic {topic} has type {info.msgtype}, expected {CONTROLLER_INFO}")
        store = bag.typestore(topic)
        tracking = store.types[CONTROLLER_INFO].STATE_TRACKING
        rows: dict[int, tuple] = {}
        controllers: set[str] = set()
        trajectory_length = 0
        show = progress and info.count >= PROGRESS_MIN_MESSAGES
        for _, _, raw in tqdm(bag.messages([topic]), total=info.count, unit="msg", disable=None if show else True):
            msg = store.deserialize_cdr(raw, CONTROLLER_INFO)
            if msg.state != tracking:
                continue
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            rows.setdefault(stamp, (
                _pose(msg.chiee), _pose(msg.chiee_des), _config(msg.q), _config(msg.q_des), msg.varphi,
                msg.varphi_des, msg.phi_ss, msg.phi_des_unsat, msg.phi_des_sat, msg.e_int, msg.saturated,
            ))  # fmt: skip
            controllers.add(msg.controller)
            trajectory_length = max(trajectory_length, msg.setpoint.trajectory_length)
    if len(rows) < 2:
        raise BagError(
            f"{path}: topic {topic} has {info.count} messages but {len(rows)} tick(s) in STATE_TRACKING "
            "(at least 2 are needed)"
        )
    stamps = np.array(sorted(rows), dtype=np.int64)
    columns = list(zip(*(rows[s] for s in stamps)))
    names = ("chiee", "chiee_des", "q", "q_des", "varphi", "varphi_des", "phi_ss", "phi_unsat", "phi_sat", "e_int")
    arrays = {name: np.array(col, dtype=np.float64) for name, col in zip(names, columns)}
    return RunLog(
        t=(stamps - stamps[0]) * 1e-9,
        saturated=np.array(columns[-1], dtype=bool),
        meta={
            "bag": str(path), "topic": topic, "controller": ",".join(sorted(controllers)),
            "trajectory_length": str(trajectory_length),
        },  # fmt: skip
        **arrays,
    )


def is_contour(log: RunLog) -> bool:
    """Whether the run tracked a contour (a setpoint trajectory of more than CONTOUR_MIN_POINTS points)."""
    return int(log.meta.get("trajectory_length", "0")) > CONTOUR_MIN_POINTS


@dataclass(frozen=True)
class Analysis:
    """Result of :func:`analyze`: the (trimmed) log, its metrics, the tables as text and the files written."""

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
    """Metrics, figures and exports of one bag into ``out`` (defaults of duration/contour: module docstring)."""
    log = runlog_from_bag(path, topic, progress)
    contour = is_contour(log) if contour is None else contour
    if duration is None:
        duration = None if contour else STEP_RUN_DURATION
    if duration is not None and not 0.0 < duration <= log.t[-1]:
        duration = None  # nothing to trim: the last step then ends one tick period after the last tick
    name = name or Path(path).stem
    try:
        metrics = evaluate_run(log.t, log.chiee_des[:, :2], log.chiee[:, :2], log.saturated, duration, name)
    except ValueError as exc:
        raise BagError(f"{path}: topic {topic} cannot be evaluated: {exc}") from exc
    if duration is not None:
        log = log.trimmed(duration)
    out.mkdir(parents=True, exist_ok=True)
    report = f"{format_summary([metrics])}\n\n{format_steps(metrics)}\n"
    files = [out / "metrics.txt"]
    files[0].write_text(report, encoding="utf8")
    files += all_figures(log, out, phi_max=phi_max, contour=contour)
    if csv:
        files.append(log.save_csv(out / "run.csv"))
    if npz:
        files.append(log.save_npz(out / "run.npz"))
    return Analysis(log, metrics, report, files)


def main(argv: list[str] | None = None) -> int:
    """Console script ``hsa_analyze``."""
    parser = cli.ArgumentParser(prog="hsa_analyze", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument("--out", type=Path, help="output directory (default out/analysis/<bag name>)")
    parser.add_argument("--duration", type=cli.non_negative,
                        help="keep 0 <= t < S [s]; default 110 for step runs, all for contours; 0 = all")
    parser.add_argument("--csv", action="store_true", help="also write run.csv (one row per tick)")
    parser.add_argument("--npz", action="store_true", help="also write run.npz (one array per field)")
    parser.add_argument("--topic", default=TOPIC, help=f"ControllerInfo topic (default {TOPIC})")
    parser.add_argument("--contour", action="store_true", default=None, help="draw the Cartesian path figure")
    parser.add_argument("--phi-max", type=cli.positive, help="[rad] actuation limit drawn in the actuation figure")
    parser.add_argument("--name", help="run name in the tables (default the bag name)")
    args = parser.parse_args(argv)
    if not args.bag.exists():
        parser.error(f"bag {args.bag} does not exist")
    name = args.name or args.bag.stem
    out = args.out or Path("out", "analysis", name)
    try:
        result = analyze(
            args.bag, out, topic=args.topic, duration=args.duration, contour=args.contour, csv=args.csv,
            npz=args.npz, phi_max=args.phi_max, name=name, progress=True,
        )  # fmt: skip
    except BagError as exc:
        print(f"hsa_analyze: {exc}", file=sys.stderr)
        return 2
    print(result.report)
    print(f"wrote {len(result.files)} files to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

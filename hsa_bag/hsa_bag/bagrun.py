"""A recorded run as a RunLog: the controller's ticks of a bag (or an offline NPZ log), its name and
kind (no ROS installation needed).

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
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hsa_bag.bagio import Bag, BagError, stamp_ns
from hsa_bag.storage import read_metadata
from hsa_core.model.params import ParameterError, load_params
from hsa_core.runs.runlog import RunLog

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
    "bag",  # file or directory names that say nothing: the run is named by its parent
)
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
            "in STATE_TRACKING (at least 2 are needed)"
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
        # newest measurement at or before each tick
        newest = np.searchsorted(measured[0], stamps, side="right") - 1
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

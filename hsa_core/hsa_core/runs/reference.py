"""The paper's real-robot step runs as reference data: conditions and time series of each run (no
ROS).

The runs ship as package data (``config/realdata/``, provenance in its README.md): four closed-loop
step runs of the ISER 2023 paper recovered from the authors' published figures, with each run's
conditions from their logbook (``runs.yaml``). :func:`load_run` returns one run; :func:`run_names`
lists them. The raw series (:class:`Trace`) keep the files' units (time [s], positions [mm], angles
[rad]); :attr:`ReferenceRun.p`, :attr:`ReferenceRun.p_des` and :meth:`ReferenceRun.rmse` are in
metres. What the data can and cannot say (resolution, repeatability) is in the README.

Step instants are read from the 100 Hz reference columns: the first grid instant at which the
reference has moved by more than :data:`STEP_THRESHOLD` (the plotted reference of the EPU run also
drifts by 0.01 mm every ~2.4 s, a drawing artefact, which is not a step).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from hsa_core.controller.control import CollocatedGains, ControllerKind, PidGains
from hsa_core.runs.profiles import RunProfile, load_profile
from hsa_core.task.trajectories import STEP_LISTS, TimedReference

DATA_DIR = Path(__file__).resolve().parents[1] / "config" / "realdata"
"""The packaged reference runs (CSV files, runs.yaml, README.md)."""
STEP_THRESHOLD = 0.5e-3
"""[m] a move of the reference larger than this between two 100 Hz samples is a step."""


@dataclass(frozen=True)
class RunConditions:
    """A run's conditions (logbook): bag name, material, law, gains, σ_a,eq per rod (None where the
    logbook's value is not known: the material's nominal), payload [kg], date and the run profile
    of its period (hsa_core.runs.profiles: control period, integrator step, velocity estimator,
    bus), with the run's own control period where the data give it."""

    bag: str
    material: str
    law: ControllerKind
    gains: CollocatedGains | PidGains
    sigma_a_eq: tuple[float, float] | None
    payload: float
    date: datetime.date
    profile: RunProfile

    @property
    def tanh_slope(self) -> float | None:
        """γ of the saturated integral [rad/(N m)] (collocated laws), None for the PID."""
        return getattr(self.gains, "gamma", None)


@dataclass(frozen=True)
class Trace:
    """Time series [t (n,), then named columns (n,) each], as one CSV file holds them."""

    t: np.ndarray
    columns: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        """The column ``name`` (as in the file's header, without its unit)."""
        return self.columns[name]


@dataclass(frozen=True)
class ReferenceRun:
    """One real run: its conditions and time series (as in the files: positions [mm]).

    ``pee`` as plotted (irregular samples), ``pee_100hz`` on a 10 ms grid with the reference as an
    exact step function; ``phi`` the commanded twists (and φ^ss for model-based laws); ``varphi``
    (model-based laws only, else None); ``q``; ``step_metrics`` the per-step table of the files
    (column name → values, step k = row k)."""

    conditions: RunConditions
    pee: Trace
    pee_100hz: Trace
    phi: Trace
    varphi: Trace | None
    q: Trace
    step_metrics: dict[str, np.ndarray]

    @property
    def t(self) -> np.ndarray:
        """[s] the 100 Hz grid."""
        return self.pee_100hz.t

    @property
    def p_des(self) -> np.ndarray:
        """(n, 2) [m] the reference on the 100 Hz grid."""
        return np.stack([self.pee_100hz["px_des"], self.pee_100hz["py_des"]], axis=1) * 1e-3

    @property
    def p(self) -> np.ndarray:
        """(n, 2) [m] the measured (mocap) end-effector position on the 100 Hz grid."""
        return np.stack([self.pee_100hz["px"], self.pee_100hz["py"]], axis=1) * 1e-3

    @property
    def step_instants(self) -> np.ndarray:
        """[s] the instants the reference changes (steps 1, 2, ...), read from the 100 Hz
        reference."""
        return step_instants(self.t, self.p_des)

    def timed_reference(self) -> TimedReference:
        """The run's setpoints (the material's step list, experiments.md §2) at the real instants:
        point 0 at t = 0, point k at step instant k; it ends where the trace ends (one 10 ms sample
        after its last)."""
        instants = self.step_instants
        points = np.asarray(STEP_LISTS[self.conditions.material], dtype=np.float64)
        if len(instants) != len(points) - 1:
            raise ValueError(
                f"{self.conditions.bag}: {len(instants)} steps in the trace, {len(points) - 1} in "
                f"the {self.conditions.material} step list"
            )
        return TimedReference(
            np.concatenate([[0.0], instants]),
            points,
            f"{self.conditions.bag}_steps",
            float(self.t[-1]) + 0.01,
        )

    def rmse(self) -> float:
        """[m] tracking RMSE over the 100 Hz grid (experiments.md §4 on these traces)."""
        return float(np.sqrt(np.mean(np.sum((self.p_des - self.p) ** 2, axis=1))))


def step_instants(
    t: np.ndarray, p_des: np.ndarray, threshold: float = STEP_THRESHOLD
) -> np.ndarray:
    """The samples of ``t`` at which ``p_des`` (n, 2) has moved by more than ``threshold`` since the
    previous one."""
    jumps = np.linalg.norm(np.diff(p_des, axis=0), axis=1) > threshold
    return np.asarray(t)[1:][jumps]


def run_names() -> tuple[str, ...]:
    """The bag names of the packaged runs, oldest first."""
    return tuple(sorted(_conditions_table()))


def load_run(bag: str) -> ReferenceRun:
    """The packaged run ``bag`` (e.g. "20230925_093236"); ValueError (one line) for an unknown
    name."""
    table = _conditions_table()
    if bag not in table:
        raise ValueError(f"unknown reference run {bag!r}; known: {', '.join(sorted(table))}")
    conditions = conditions_of(bag, table[bag])
    varphi = DATA_DIR / f"{bag}_varphi.csv"
    return ReferenceRun(
        conditions,
        _trace(f"{bag}_pee.csv"),
        _trace(f"{bag}_pee_100Hz.csv"),
        _trace(f"{bag}_phi.csv"),
        _trace(varphi.name) if varphi.is_file() else None,
        _trace(f"{bag}_q.csv"),
        _table(DATA_DIR / f"{bag}_step_metrics.csv"),
    )


def _conditions_table() -> dict[str, dict]:
    """runs.yaml: bag → its conditions as written."""
    return {str(k): v for k, v in yaml.safe_load((DATA_DIR / "runs.yaml").read_text()).items()}


def conditions_of(bag: str, entry: dict) -> RunConditions:
    """Typed conditions of one run's entry (runs.yaml, paper_runs.yaml; its ``profile`` names a
    packaged run profile, its optional ``control_period_ms`` replaces that profile's period, its
    ``sigma_a_eq`` may be null)."""
    law = ControllerKind(entry["law"])
    gains = (
        PidGains(**entry["gains"])
        if law is ControllerKind.PID
        else CollocatedGains(**entry["gains"])
    )
    date = (
        entry["date"]
        if isinstance(entry["date"], datetime.date)
        else datetime.date.fromisoformat(entry["date"])
    )
    sigma = entry["sigma_a_eq"]
    profile = load_profile(str(entry["profile"]))
    if "control_period_ms" in entry:
        profile = replace(profile, control_period_ms=entry["control_period_ms"])
    return RunConditions(
        bag,
        str(entry["material"]),
        law,
        gains,
        None if sigma is None else (float(sigma[0]), float(sigma[1])),
        float(entry["payload"]),
        date,
        profile,
    )


def _trace(name: str) -> Trace:
    """One CSV time series: header 't [s],name [unit],...' → Trace with the names without units."""
    path = DATA_DIR / name
    header = path.read_text().split("\n", 1)[0].split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    names = [h.split(" [")[0] for h in header]
    return Trace(data[:, 0], {n: data[:, i] for i, n in enumerate(names) if i > 0})


def _table(path: Path) -> dict[str, np.ndarray]:
    """The step-metrics CSV: column → values (numbers where the column is numeric, else strings)."""
    raw = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8")
    return {name: np.asarray(raw[name]) for name in raw.dtype.names}

"""The per-controller-tick record of a closed-loop run, shared by the offline experiment and the bag
analysis.

One row per controller tick, exactly the quantities of the controller-info message, so that figures
and metrics are computed the same way whether the run came from the offline simulator or from a
recorded bag; optionally the measured twist ``phi_meas`` (the newest ``/hsa/phi_present`` at each
tick). Export to NPZ (one array per field) and CSV (one column per scalar component, its unit in the
header: ``t [s]``, ``chiee_x [m]``, ``phi_sat_1 [rad]``) for people who analyse in their own tools.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# field name -> component labels (CSV column suffixes); order defines the CSV layout
COLUMNS: dict[str, tuple[str, ...]] = {
    "t": ("",),
    "chiee": ("x", "y", "theta"),
    "chiee_des": ("x", "y", "theta"),
    "q": ("kappa_be", "sigma_sh", "sigma_ax"),
    "q_des": ("kappa_be", "sigma_sh", "sigma_ax"),
    "varphi": ("1", "2", "3"),
    "varphi_des": ("1", "2", "3"),
    "phi_ss": ("1", "2"),
    "phi_unsat": ("1", "2"),
    "phi_sat": ("1", "2"),
    "e_int": ("1", "2"),
    "saturated": ("",),
}
# absent (None) when not measured
OPTIONAL_COLUMNS: dict[str, tuple[str, ...]] = {"phi_meas": ("1", "2")}

_POSE_UNITS = ("m", "m", "rad")
_Q_UNITS = ("rad/m", "-", "-")
_VARPHI_UNITS = ("N m/rad", "N m/rad", "-")
UNITS: dict[str, tuple[str, ...]] = {
    "t": ("s",),
    "chiee": _POSE_UNITS,
    "chiee_des": _POSE_UNITS,
    "q": _Q_UNITS,
    "q_des": _Q_UNITS,
    "varphi": _VARPHI_UNITS,
    "varphi_des": _VARPHI_UNITS,
    "phi_ss": ("rad", "rad"),
    "phi_unsat": ("rad", "rad"),
    "phi_sat": ("rad", "rad"),
    "e_int": ("s", "s"),
    "saturated": ("-",),
    "phi_meas": ("rad", "rad"),
}
"""SI unit of every CSV column; e_int is in s for the collocated laws and in m s for the PID (see
:func:`units`)."""


def units(name: str, controller: str = "") -> tuple[str, ...]:
    """Units of the components of field ``name`` (the PID's integral state integrates a position
    error: m s)."""
    if name == "e_int" and controller.startswith("pid"):
        return ("m s", "m s")
    return UNITS[name]


@dataclass
class RunLog:
    """Controller-tick time series of one run (t in s from the first controller output; SI units
    throughout)."""

    t: np.ndarray
    chiee: np.ndarray
    chiee_des: np.ndarray
    q: np.ndarray
    q_des: np.ndarray
    varphi: np.ndarray
    varphi_des: np.ndarray
    phi_ss: np.ndarray
    phi_unsat: np.ndarray
    phi_sat: np.ndarray
    e_int: np.ndarray
    saturated: np.ndarray
    # (N, 2) [rad] measured twist at each tick, NaN before the first measurement
    phi_meas: np.ndarray | None = None
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check that every field has one row per tick and the documented width."""
        n = len(self.t)
        for name, labels in self.columns().items():
            arr = np.asarray(getattr(self, name))
            width = len(labels)
            if arr.shape[0] != n or (width > 1 and arr.shape[1:] != (width,)):
                raise ValueError(
                    f"RunLog.{name} has shape {arr.shape}, expected "
                    f"({n}{', ' + str(width) if width > 1 else ''})"
                )

    def __len__(self) -> int:
        return len(self.t)

    def columns(self) -> dict[str, tuple[str, ...]]:
        """The fields this log holds (COLUMNS, plus the optional ones that are present) with their
        component labels."""
        present = {k: v for k, v in OPTIONAL_COLUMNS.items() if getattr(self, k) is not None}
        return {**COLUMNS, **present}

    def trimmed(self, duration: float) -> RunLog:
        """The ticks with 0 <= t < duration (the paper's metrics use the first 110 s of a step
        run)."""
        keep = (self.t >= 0.0) & (self.t < duration)
        return RunLog(
            **{name: getattr(self, name)[keep] for name in self.columns()}, meta=dict(self.meta)
        )

    def save_npz(self, path: Path) -> Path:
        """Write every field as an array (meta as strings)."""
        arrays = {name: np.asarray(getattr(self, name)) for name in self.columns()}
        arrays.update({f"meta_{k}": np.asarray(str(v)) for k, v in self.meta.items()})
        np.savez(path, **arrays)
        return path

    @classmethod
    def load_npz(cls, path: Path) -> RunLog:
        """Read a file written by :meth:`save_npz`."""
        with np.load(path) as data:
            meta = {k[5:]: str(data[k]) for k in data.files if k.startswith("meta_")}
            optional = {name: data[name] for name in OPTIONAL_COLUMNS if name in data.files}
            return cls(**{name: data[name] for name in COLUMNS}, **optional, meta=meta)

    def save_csv(self, path: Path) -> Path:
        """Write one row per tick, one column per scalar component with its unit (e.g. ``chiee_x
        [m]``)."""
        header, blocks = [], []
        controller = self.meta.get("controller", "")
        for name, labels in self.columns().items():
            arr = np.asarray(getattr(self, name), dtype=float).reshape(len(self), -1)
            header += [
                f"{name}_{lab} [{unit}]" if lab else f"{name} [{unit}]"
                for lab, unit in zip(labels, units(name, controller))
            ]
            blocks.append(arr)
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(header)
            writer.writerows(np.hstack(blocks).tolist())
        return path

"""The per-controller-tick record of a closed-loop run, shared by the offline experiment and the bag analysis.

One row per controller tick, exactly the quantities of the controller-info message, so that figures and metrics are
computed the same way whether the run came from the offline simulator or from a recorded bag. Export to NPZ (one
array per field) and CSV (one column per scalar component) for people who analyse in their own tools.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field, fields
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


@dataclass
class RunLog:
    """Controller-tick time series of one run (t in s from the first controller output; SI units throughout)."""

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
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check that every field has one row per tick and the documented width."""
        n = len(self.t)
        for name, labels in COLUMNS.items():
            arr = np.asarray(getattr(self, name))
            width = len(labels)
            if arr.shape[0] != n or (width > 1 and arr.shape[1:] != (width,)):
                raise ValueError(f"RunLog.{name} has shape {arr.shape}, expected ({n}{', ' + str(width) if width > 1 else ''})")

    def __len__(self) -> int:
        return len(self.t)

    def trimmed(self, duration: float) -> RunLog:
        """The ticks with 0 <= t < duration (the paper's metrics use the first 110 s of a step run)."""
        keep = (self.t >= 0.0) & (self.t < duration)
        return RunLog(**{f.name: getattr(self, f.name)[keep] for f in fields(self) if f.name != "meta"},
                      meta=dict(self.meta))

    def save_npz(self, path: Path) -> Path:
        """Write every field as an array (meta as strings)."""
        arrays = {name: np.asarray(getattr(self, name)) for name in COLUMNS}
        arrays.update({f"meta_{k}": np.asarray(str(v)) for k, v in self.meta.items()})
        np.savez(path, **arrays)
        return path

    @classmethod
    def load_npz(cls, path: Path) -> RunLog:
        """Read a file written by :meth:`save_npz`."""
        with np.load(path) as data:
            meta = {k[5:]: str(data[k]) for k in data.files if k.startswith("meta_")}
            return cls(**{name: data[name] for name in COLUMNS}, meta=meta)

    def save_csv(self, path: Path) -> Path:
        """Write one row per tick, one column per scalar component (e.g. chiee_x, phi_sat_2)."""
        header, blocks = [], []
        for name, labels in COLUMNS.items():
            arr = np.asarray(getattr(self, name), dtype=float).reshape(len(self), -1)
            header += [f"{name}_{lab}" if lab else name for lab in labels]
            blocks.append(arr)
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(header)
            writer.writerows(np.hstack(blocks).tolist())
        return path

"""Run profiles: the set-up of a run that is a condition of the run, not a knob (no ROS).

A profile names what the controller side and the rig of a period really were: the control period
achieved, the step of the integrators, the velocity estimator, the Dynamixel bus speed, and defaults
for σ_a,eq and the payload (a reference run's own values override those two). The profiles are data
(``config/realdata/profiles.yaml``, sources cited there); :func:`load_profile` returns one,
:func:`profile_names` lists them. ``lab`` is today's default of ``hsa_experiment`` exactly. What
each profile sets, and its evidence, is in docs/simulation.md ("Run profiles").

Velocity estimators (:class:`VelocityEstimator`):

* ``savitzky_golay_20``: the causal Savitzky–Golay end-point fit over the last 20 mocap samples,
  cubic, fed at the mocap rate (spec planning_and_control.md §6.4; the kinematics node's code path).
* ``smoothing_spline_16``: September 2023, when the control node fitted a cubic smoothing spline
  (smoothing 1.0) to the last 16 samples it had seen at its ticks (§6.4, "History"). The original
  code is not available, so this is a stand-in: the least-squares cubic through those 16 samples
  (the newest mocap state at each control tick, on their stamps), differentiated at the newest one.
  It is what a FITPACK smoothing spline with s = 1.0 reduces to when the cubic's residual is below s
  (no interior knot), as for millimetre-scale motion in SI units; it is not fitted to the data.

The control period is a whole number of milliseconds (the world's 1 ms grid); jitter of the period
is not modelled. ``bus_baud`` is recorded as a condition. ``command_latency_ms`` is the delay that
the period's controller side adds between a tick and the goal in force on the bus (its way of
writing goals); it adds to the world's actuation latency
(:func:`hsa_core.sim.run_conditions.run_disturbance`, the one place every path takes it from).
``command_queue_depth`` and ``command_transaction_ms`` (depth 0: none) send the goals through the
September driver's queue instead (:mod:`hsa_core.sim.command_queue`, by the same path).
"""

from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass, fields
from pathlib import Path

import yaml

PROFILES_FILE = Path(__file__).resolve().parents[1] / "config" / "realdata" / "profiles.yaml"
"""The packaged profiles."""
DEFAULT_PROFILE = "lab"
"""The profile of a run that names none (today's defaults)."""


class VelocityEstimator(str, enum.Enum):
    """The controller side's velocity estimate (module doc; planning_and_control.md §6.4)."""

    SAVITZKY_GOLAY_20 = "savitzky_golay_20"  # causal SG, 20 samples, cubic, at the mocap rate
    SMOOTHING_SPLINE_16 = (
        "smoothing_spline_16"  # September 2023 stand-in: cubic fit over 16 control-rate samples
    )


@dataclass(frozen=True)
class RunProfile:
    """A named set-up: control period [ms], integrator step [s] (None: the period), estimator, bus
    [bit/s], σ_a,eq per rod (None: the material's nominal), payload [kg], command latency [ms], the
    command queue's depth (0: none) and transaction time [ms], and a one-line description."""

    name: str
    description: str
    control_period_ms: int
    integrator_dt: float | None
    velocity_estimator: VelocityEstimator
    bus_baud: int
    sigma_a_eq: tuple[float, float] | None
    payload: float
    command_latency_ms: int = 0
    command_queue_depth: int = 0
    command_transaction_ms: int = 0

    def __post_init__(self) -> None:
        """Reject a period that is not a whole positive number of ms, a non-positive step or a
        negative payload."""
        if (
            isinstance(self.control_period_ms, bool)
            or not isinstance(self.control_period_ms, int)
            or self.control_period_ms < 1
        ):
            raise ValueError(
                f"profile {self.name}: control_period_ms must be a whole number of ms >= 1, "
                f"got {self.control_period_ms!r}"
            )
        if self.integrator_dt is not None and not (
            math.isfinite(self.integrator_dt) and self.integrator_dt > 0.0
        ):
            raise ValueError(
                f"profile {self.name}: integrator_dt must be > 0 or null, got "
                f"{self.integrator_dt!r}"
            )
        if not (math.isfinite(self.payload) and self.payload >= 0.0):
            raise ValueError(f"profile {self.name}: payload must be >= 0 kg, got {self.payload!r}")
        if self.sigma_a_eq is not None and not all(
            math.isfinite(s) and s > 0.0 for s in self.sigma_a_eq
        ):
            raise ValueError(
                f"profile {self.name}: sigma_a_eq must be two values > 0, got {self.sigma_a_eq!r}"
            )
        for field, value in (
            ("command_latency_ms", self.command_latency_ms),
            ("command_queue_depth", self.command_queue_depth),
            ("command_transaction_ms", self.command_transaction_ms),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(
                    f"profile {self.name}: {field} must be a whole number >= 0, got {value!r}"
                )
        if self.command_queue_depth and not self.command_transaction_ms:
            raise ValueError(
                f"profile {self.name}: a command queue needs command_transaction_ms >= 1"
            )

    @property
    def rate(self) -> float:
        """[Hz] the control rate, 1000 / control_period_ms."""
        return 1000.0 / self.control_period_ms


def profile_names() -> tuple[str, ...]:
    """The packaged profiles' names, as in the file."""
    return tuple(_table())


def load_profile(name: str) -> RunProfile:
    """The packaged profile ``name``; ValueError (one line) for an unknown name."""
    table = _table()
    if name not in table:
        raise ValueError(f"unknown run profile {name!r}; known: {', '.join(table)}")
    return table[name]


@functools.cache
def _table() -> dict[str, RunProfile]:
    """profiles.yaml: name → typed profile (every entry must have exactly the fields of
    RunProfile)."""
    raw = yaml.safe_load(PROFILES_FILE.read_text())
    expected = {f.name for f in fields(RunProfile)} - {"name"}
    table = {}
    for name, entry in raw.items():
        if set(entry) != expected:
            raise ValueError(
                f"{PROFILES_FILE.name}: profile {name} needs exactly {sorted(expected)}, got "
                f"{sorted(entry)}"
            )
        sigma = entry["sigma_a_eq"]
        table[str(name)] = RunProfile(
            str(name),
            str(entry["description"]),
            entry["control_period_ms"],
            None if entry["integrator_dt"] is None else float(entry["integrator_dt"]),
            VelocityEstimator(entry["velocity_estimator"]),
            int(entry["bus_baud"]),
            None if sigma is None else (float(sigma[0]), float(sigma[1])),
            float(entry["payload"]),
            entry["command_latency_ms"],
            entry["command_queue_depth"],
            entry["command_transaction_ms"],
        )
    return table

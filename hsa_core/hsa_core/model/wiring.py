"""The wiring of one robot, defined once: which Dynamixel drives which virtual rod, in which sense,
and its neutral.

The driver (real servos), the simulator (emulated servos), the controller (``motor_goal_angles``)
and the offline simulations all build their :class:`~hsa_core.model.actuation.MotorMap` through
:meth:`Wiring.motor_map`, so motor IDs and rod signs cannot disagree between them. Handedness ``h``
and the twist limit are properties of the rods: they come from the model parameter set's
:class:`~hsa_core.model.params.PhiLimit` (``params.phi_limit``), the one φ limit that the planner,
the validator, the controller's clip and the driver's goal clamp all use.

File format (packaged: ``config/robots/lab.yaml``): ``motor_ids``, ``rod`` (0-based virtual rod per
motor), ``rho`` (±1 per motor) and ``neutral_ticks`` (nominal φ = 0 positions), one entry per motor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hsa_core.model.actuation import MotorMap, check_wiring
from hsa_core.model.params import CONFIG_DIR, HsaParams

ROBOTS_DIR = CONFIG_DIR / "robots"
DEFAULT_ROBOT = "lab"
_KEYS = ("motor_ids", "rod", "rho", "neutral_ticks")


class WiringError(ValueError):
    """A wiring file that is missing, unreadable or inconsistent (the message names the file and the
    key)."""


@dataclass(frozen=True)
class Wiring:
    """Motor IDs, the virtual rod and rod sign of each motor, and the nominal neutral ticks of one
    robot."""

    motor_ids: tuple[int, ...]
    rod: tuple[int, ...]
    rho: tuple[int, ...]
    neutral_ticks: tuple[int, ...]
    source: str = DEFAULT_ROBOT

    def motor_map(
        self, params: HsaParams, neutral_ticks: tuple[int, ...] | None = None, margin: float = 0.02
    ) -> MotorMap:
        """The φ ↔ ticks map of this robot with ``params``' handedness and motor twist limit
        (``PhiLimit.motor``); neutral: nominal or given."""
        ticks = (
            self.neutral_ticks if neutral_ticks is None else tuple(int(t) for t in neutral_ticks)
        )
        limit = params.phi_limit
        return MotorMap(
            ticks,
            self.motor_ids,
            self.rod,
            self.rho,
            h=limit.handedness,
            phi_max=limit.motor,
            margin=margin,
        )


def wiring_path(source: str | Path = "") -> Path:
    """The file of a packaged robot name ("" = the lab robot) or of a path."""
    name = str(source) or DEFAULT_ROBOT
    packaged = ROBOTS_DIR / f"{name}.yaml"
    return packaged if Path(name).name == name and packaged.is_file() else Path(name)


def load_wiring(source: str | Path = "") -> Wiring:
    """The wiring of a packaged robot ("" or "lab") or of a YAML file; WiringError says what is
    wrong."""
    path = wiring_path(source)
    try:
        data: Any = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise WiringError(f"wiring file {path}: cannot be read ({exc})") from exc
    if not isinstance(data, dict):
        raise WiringError(f"wiring file {path}: expected a mapping with keys {', '.join(_KEYS)}")
    unknown = sorted(set(data) - set(_KEYS))
    if unknown:
        raise WiringError(
            f"wiring file {path}: unknown key '{unknown[0]}' (keys: {', '.join(_KEYS)})"
        )
    values = {}
    for key in _KEYS:
        value = data.get(key)
        if not isinstance(value, list) or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in value
        ):
            raise WiringError(
                f"wiring file {path}: key '{key}' must be a list of integers, got {value!r}"
            )
        values[key] = tuple(value)
    wiring = Wiring(**values, source=str(path))
    try:  # one entry per motor, distinct IDs, every rod driven, signs ±1
        check_wiring(wiring.neutral_ticks, wiring.motor_ids, wiring.rod, wiring.rho)
    except ValueError as exc:
        raise WiringError(f"wiring file {path}: {exc}") from exc
    if not all(0 <= i <= 252 for i in wiring.motor_ids):
        raise WiringError(
            f"wiring file {path}: key 'motor_ids' must lie in 0 … 252, got {list(wiring.motor_ids)}"
        )
    return wiring

"""Neutral ticks of the dynamixel_driver: where the configured neutral comes from, and the persisted
calibration file.

The configured neutral fixes the absolute goal limits before the bus is opened: the
``neutral_ticks`` parameter, or the ``neutral_file`` written once from the present positions at the
first start (the decision whether those may be stored is
`hsa_core.driver.servo_supervision.PositionCheck.first_calibration`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import yaml

from hsa_common.parameters import ParameterValidationError


def read_neutral_file(path: Path, ids: list[int]) -> list[int]:
    """Neutral ticks stored in ``path`` for ``ids``; ValueError says what is wrong with the file."""
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict) or data.get("ids") != ids:
        raise ValueError(f"{path} is not a neutral file for motor IDs {ids}")
    ticks = data.get("neutral_ticks")
    if not (
        isinstance(ticks, list) and len(ticks) == len(ids) and all(type(t) is int for t in ticks)
    ):
        raise ValueError(f"{path}: neutral_ticks must be {len(ids)} integers, got {ticks!r}")
    return ticks


def write_neutral_file(path: Path, ids: list[int], ticks: list[int]) -> None:
    """Store the neutral ticks (atomic replace) so later starts can check the robot starts
    untwisted."""
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_name(path.name + ".tmp")
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    staging.write_text(
        f"# neutral ticks of the HSA motors, stored by dynamixel_driver at {stamp}\n"
        + yaml.safe_dump({"ids": ids, "neutral_ticks": ticks}, default_flow_style=None)
    )
    staging.replace(path)


def configured_neutral(
    p: dict[str, Any], ids: list[int], nominal: tuple[int, ...]
) -> list[int] | None:
    """Neutral ticks fixed before the bus is opened (param, else the wiring's ``nominal``; read's
    reference; or an existing file), or None (the first start with neutral_source 'file': the
    calibration is written from the present positions)."""
    source, path = p["neutral_source"], p["neutral_file"]
    if source in ("param", "read"):
        return list(p["neutral_ticks"] or nominal)
    if source == "file":
        if not path:
            raise ParameterValidationError(
                "parameter 'neutral_file' must be set when neutral_source is 'file'"
            )
        if Path(path).exists():
            try:
                return read_neutral_file(Path(path), ids)
            except (OSError, ValueError, yaml.YAMLError) as exc:
                raise ParameterValidationError(f"parameter 'neutral_file': {exc}") from exc
    return None

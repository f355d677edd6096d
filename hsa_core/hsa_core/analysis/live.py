"""Live-view payloads: what the plot, diagnostics and progress channels of hsa_live carry, from
plain numbers.

ROS-free and Foxglove-free: the node (hsa_live) feeds these functions the fields of the messages it
receives and logs their results as JSON messages. Units are SI (m, rad, s); names as in the paper
(p_ee, p^d, e = p^d − p_ee as in hsa_core.analysis.metrics, φ, φ^ss, q). JSON has no NaN, and the
viewers of the Foxglove family read a JSON-schema field type only as one string (``"number"``, never
``["number", "null"]``): a non-finite value is left out of the payload (:func:`finite`), so a tick
that sent no command (φ NaN in controller_info) has no φ field, a gap in the plot.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

CONTROLLER_STATES = (
    "waiting for setpoint",
    "waiting for state",
    "tracking",
    "holding (stale)",
    "stopped (E-stop)",
    "driver torque off",
)
"""Names of hsa_msgs/ControllerInfo ``state`` codes 0-5 (STATE_WAITING_FOR_SETPOINT …
STATE_TORQUE_OFF)."""
LEVELS = ("OK", "WARN", "ERROR", "STALE")
"""Names of diagnostic_msgs/DiagnosticStatus levels 0-3."""
Q_NAMES = ("kappa_be", "sigma_sh", "sigma_ax")
"""Components of q [1/m, -, -]."""


def number(value: float) -> float | None:
    """``value`` as a float, or None when it is not finite (left out of a payload by
    :func:`finite`)."""
    value = float(value)
    return value if math.isfinite(value) else None


def numbers(values: Iterable[float]) -> list[float | None]:
    """Each value as by :func:`number`."""
    return [number(v) for v in values]


def finite(payload: Mapping[str, Any]) -> dict[str, Any]:
    """``payload`` without its missing values, nested mappings included: a member that is None, or a
    list holding a None, is left out (a viewer shows an absent field as a gap; the schema's types
    stay single)."""
    kept: dict[str, Any] = {}
    for key, value in payload.items():
        if isinstance(value, Mapping):
            value = finite(value)
        if value is None or (isinstance(value, list) and any(v is None for v in value)):
            continue
        kept[key] = value
    return kept


def point(xy: Sequence[float]) -> dict[str, float | None]:
    """A planar position [x, y] as {"x", "y"} [m] (None where not finite)."""
    return {"x": number(xy[0]), "y": number(xy[1])}


def tracking_sample(p_ee: Sequence[float], p_des: Sequence[float]) -> dict[str, Any]:
    """Measured EE position, reference and error e = p^d − p_ee with its norm ‖e‖ [m] of one
    controller tick."""
    ex, ey = float(p_des[0]) - float(p_ee[0]), float(p_des[1]) - float(p_ee[1])
    return finite(
        {
            "p_ee": point(p_ee),
            "p_des": point(p_des),
            "e": {"x": number(ex), "y": number(ey)},
            "e_norm": number(math.hypot(ex, ey)),
        }
    )


def actuation_sample(
    phi_cmd: Sequence[float],
    phi_unsat: Sequence[float],
    phi_ss: Sequence[float],
    phi_min: Sequence[float],
    phi_max: Sequence[float],
    saturated: bool,
) -> dict[str, Any]:
    """Commanded φ (after saturation), the law's output before it, φ^ss and the admissible box per
    rod [rad]; a list with a non-finite value (no command sent) is left out."""
    return finite(
        {
            "phi_cmd": numbers(phi_cmd),
            "phi_unsat": numbers(phi_unsat),
            "phi_ss": numbers(phi_ss),
            "phi_min": numbers(phi_min),
            "phi_max": numbers(phi_max),
            "saturated": bool(saturated),
        }
    )


def configuration_sample(q: Sequence[float], q_des: Sequence[float]) -> dict[str, Any]:
    """Measured q and desired q^d of one controller tick, by component name [1/m, -, -]."""
    return finite(
        {"q": dict(zip(Q_NAMES, numbers(q))), "q_des": dict(zip(Q_NAMES, numbers(q_des)))}
    )


def phi_present_sample(phi: Sequence[float]) -> dict[str, Any]:
    """Measured φ per rod [rad] (left out when not finite)."""
    return finite({"phi": numbers(phi)})


def controller_state_name(code: int) -> str:
    """Name of a ControllerInfo ``state`` code; unknown codes are named by number."""
    return CONTROLLER_STATES[code] if 0 <= code < len(CONTROLLER_STATES) else f"state {code}"


class Throttle:
    """Lets at most one event through per ``1/rate`` seconds of the times passed in [ns]; the others
    are dropped.

    Times are integer nanoseconds (``time.monotonic_ns()``, a ROS clock's), so a stream on an exact
    grid (200 Hz states, 25 Hz scene) passes exactly every 8th event, with no rounding loss. A time
    earlier than the last accepted one (a clock reset, e.g. a restarted simulation) is accepted and
    restarts the count, so the view never freezes waiting for a time that will not come.
    """

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self._last: int | None = None

    @property
    def rate(self) -> float:
        """[Hz] largest rate of accepted events."""
        return 1e9 / self._period

    @rate.setter
    def rate(self, rate: float) -> None:
        if not rate > 0.0:
            raise ValueError(f"rate must be > 0 Hz, got {rate}")
        self._period = round(1e9 / rate)

    def due(self, now: int) -> bool:
        """Whether an event at time ``now`` [ns] goes through (it then becomes the last accepted
        one)."""
        if self._last is not None and 0 <= now - self._last < self._period:
            return False
        self._last = now
        return True


@dataclass
class DiagnosticsTable:
    """The newest status of every diagnostic name seen on /diagnostics, with a STALE mark for silent
    ones."""

    stale_after: float
    """[s] a status not refreshed for longer than this is shown with level STALE (its node may be
    gone)."""
    _rows: dict[str, tuple[int, str, float]] = field(default_factory=dict)

    def update(self, name: str, level: int, message: str, now: float) -> None:
        """Record status ``name`` with its level code and message, received at ``now`` [s]."""
        self._rows[name] = (int(level), message, now)

    def snapshot(self, now: float) -> dict[str, Any]:
        """Rows sorted by name (level, level name, message, age [s]), the worst level and the count
        per level."""
        rows = []
        for name in sorted(self._rows):
            level, message, seen = self._rows[name]
            age = now - seen
            if age > self.stale_after:
                level = LEVELS.index("STALE")
            rows.append(
                {
                    "name": name,
                    "level": level,
                    "level_name": _level_name(level),
                    "message": message,
                    "age": round(max(age, 0.0), 3),
                }
            )
        worst = max((r["level"] for r in rows), default=0)
        counts = {name: sum(r["level"] == code for r in rows) for code, name in enumerate(LEVELS)}
        return {
            "worst": worst,
            "worst_name": _level_name(worst),
            "counts": counts,
            "statuses": rows,
        }


def _level_name(level: int) -> str:
    """Name of a DiagnosticStatus level code."""
    return LEVELS[level] if 0 <= level < len(LEVELS) else f"level {level}"


def progress(
    sequencer_status: str | None, controller_state: int | None, e_norm: float | None
) -> dict[str, Any]:
    """Run progress from the sequencer's JSON status, the controller's state code and the newest ‖e‖
    [m].

    ``step`` counts from 1 (the setpoint point now active), ``steps`` is the trajectory length;
    ``text`` is the one line a viewer shows, e.g. "step 3/11 · tracking · ‖e‖ 1.25 mm". Missing
    inputs (no status or no controller_info yet) are reported as such, never invented.
    """
    status: Mapping[str, Any] = {}
    if sequencer_status:
        try:
            parsed = json.loads(sequencer_status)
            status = parsed if isinstance(parsed, dict) else {}
        except ValueError:
            status = {}
    index = int(status.get("setpoint_index", status.get("index", -1)) if status else -1)
    steps = int(status.get("length", 0)) if status else 0
    finished = bool(status.get("finished", False))
    failures = int(status.get("failures", 0)) if status else 0
    mode = (
        controller_state_name(controller_state)
        if controller_state is not None
        else "no controller_info yet"
    )
    error = number(e_norm) if e_norm is not None else None
    parts = [
        f"step {index + 1}/{steps}"
        if status and index >= 0
        else ("no setpoint yet" if status else "no sequencer status yet"),
        mode,
    ]
    if error is not None:
        parts.append(f"‖e‖ {error * 1e3:.2f} mm")
    if finished:
        parts.append("finished")
    if failures:
        parts.append(f"{failures} failed")
    return finite(
        {
            "step": index + 1 if index >= 0 else 0,
            "steps": steps,
            "finished": finished,
            "failures": failures,
            "sequencer_state": str(status.get("state", "")),
            "trajectory": str(status.get("trajectory", "")),
            "controller_state": mode,
            "e_norm": error,
            "text": " · ".join(parts),
        }
    )


def json_schema(title: str, sample: Any) -> dict[str, Any]:
    """JSON schema (draft 2020-12 subset) of a payload shaped like ``sample``, every field of one
    type (a string, as the Foxglove-family viewers require); a missing value is an absent field, not
    a null."""
    return {"title": title, **_schema_of(sample)}


def _schema_of(value: Any) -> dict[str, Any]:
    """Schema of one value: objects by their keys, arrays by their first item, numbers as
    "number"."""
    if isinstance(value, dict):
        return {"type": "object", "properties": {k: _schema_of(v) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return {"type": "array", "items": _schema_of(value[0]) if value else {}}
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, int):
        return {"type": "integer"}
    return {"type": "number"}

"""/diagnostics publishing without diagnostic_updater (not among the Jazzy wheels): one
DiagnosticArray per period.

Each node registers named checks; a check returns a level, a message and key/values. Counters that
only ever grow (rejected samples, bus errors) are kept by the node and reported here, so nothing is
lost between periods.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

OK, WARN, ERROR, STALE = (
    DiagnosticStatus.OK,
    DiagnosticStatus.WARN,
    DiagnosticStatus.ERROR,
    DiagnosticStatus.STALE,
)


def log_level_change(logger: object, previous: bytes | None, level: bytes, message: str) -> bytes:
    """Log ``message`` at the severity of ``level`` when it differs from ``previous``; returns
    ``level``.

    Nodes log their diagnostic state changes once this way, not on every report. One call line per
    severity: rclpy refuses a call site whose severity changes between calls.
    """
    if level != previous:
        if level == OK:
            logger.info(message)  # type: ignore[attr-defined]
        elif level == WARN:
            logger.warning(message)  # type: ignore[attr-defined]
        else:
            logger.error(message)  # type: ignore[attr-defined]
    return level


@dataclass(frozen=True)
class Report:
    """Result of one diagnostic check."""

    level: bytes
    message: str
    values: Mapping[str, object]


Check = Callable[[], Report]


class Diagnostics:
    """Publishes the registered checks of a node on /diagnostics every ``period`` seconds."""

    def __init__(self, node: Node, period: float = 1.0, hardware_id: str = "") -> None:
        self._node = node
        self._checks: dict[str, Check] = {}
        self._hardware_id = hardware_id
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._timer = node.create_timer(period, self.publish)

    def add(self, name: str, check: Check) -> None:
        """Register a check under ``<node name>: <name>``."""
        self._checks[name] = check

    def publish(self) -> None:
        """Run every check and publish one DiagnosticArray (a failing check is reported, never
        raised)."""
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        for name, check in self._checks.items():
            try:
                report = check()
            except Exception as exc:  # a broken check must not take the node down
                report = Report(ERROR, f"check failed: {exc!r}", {})
            msg.status.append(
                DiagnosticStatus(
                    level=report.level,
                    name=f"{self._node.get_name()}: {name}",
                    message=report.message,
                    hardware_id=self._hardware_id,
                    values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()],
                )
            )
        self._pub.publish(msg)

"""The dynamixel_driver's /diagnostics statuses (bus, servos, control, estop), built from the state
of `Servos`.

Levels and values: docs/nodes/hsa_dynamixel_driver.md, section Diagnostics.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_core.driver.servo_supervision import Watchdog
from hsa_core.rate_meter import RateMeter
from hsa_dynamixel_driver.bus import describe_hardware_error
from hsa_dynamixel_driver.servos import Servos

ERROR_COUNTS = (
    "bus_losses",
    "reconnect_attempts",
    "reconnects",
    "port_errors",
    "comm_errors",
    "status_errors",
)
COMMAND_COUNTS = ("commands", "rejected", "clamped", "rate_limited", "ignored")
RATE_COUNTS = ("cycles", "writes", "reads")


def bus_report(servos: Servos, p: dict[str, Any]) -> Report:
    """OK connected; WARN failures in a row or not configured; ERROR disconnected (with the
    reason)."""
    sup = servos.sup
    link = sup.link
    outage = "none" if link.last_outage_s is None else f"{link.last_outage_s:.3f} s"
    values = {
        "port": p["port"],
        "baudrate": p["baudrate"],
        "latency_timer": servos.latency,
        **{k: servos.counts[k] for k in ERROR_COUNTS},
        "last_outage": outage,
        "consecutive_failures": link.consecutive_failures,
        "last_error": servos.last_error,
    }
    if servos.bus is None:
        return Report(WARN, "not configured", values)
    if not link.up:
        return Report(ERROR, f"disconnected: {link.problem}", values)
    return Report(WARN if link.consecutive_failures else OK, "connected", values)


def servo_report(servos: Servos, p: dict[str, Any]) -> Report:
    """OK; WARN torque off on request or relaxed; ERROR torque wanted but refused, a hardware error,
    or the E-stop."""
    sup, limits = servos.sup, servos.limits
    values = {
        "torque": sup.note,
        "torque_on_failures_in_a_row": sup.retry.failures,
        "torque_retry_pending": sup.retry.at is not None,
        "neutral_ticks": list(servos.map.neutral_ticks) if servos.map else [],
        "neutral_source": p["neutral_source"],
        "goal_limits": [[int(lo), int(hi)] for lo, hi in zip(limits.lower, limits.upper)]
        if limits
        else [],
        "held_at_start": sup.positions.held,
        "reboots": servos.counts["reboots"],
        "last_reboot": servos.last_reboot,
        **{
            f"hardware_error_{i}": describe_hardware_error(sup.hardware.errors.get(i, 0))
            for i in servos.ids
        },
    }
    if sup.hardware.errors:
        return Report(ERROR, sup.hardware.problem() or "", values)
    if sup.estop.reason is not None:
        return Report(ERROR, f"torque off: E-stop engaged ({sup.estop.reason})", values)
    if sup.active and not sup.torque_on:
        unwanted = sup.torque_wanted and not sup.relaxed
        return Report(ERROR if unwanted else WARN, f"torque off: {sup.note}", values)
    return Report(OK, f"torque {'on' if sup.torque_on else 'off'}", values)


class ControlReport:
    """OK; WARN watchdog expired. Rates are per second of node clock since the previous report."""

    def __init__(self, servos: Servos, p: dict[str, Any], now_ns: int) -> None:
        """Start counting rates at ``now_ns`` [ns], with every counter at 0."""
        self._servos, self._p = servos, p
        self._rates = RateMeter(now_ns)

    def __call__(self, now_ns: int) -> Report:
        """The control status at ``now_ns`` [ns]."""
        counts, sup, p, now = self._servos.counts, self._servos.sup, self._p, now_ns * 1e-9
        rates = {
            f"{k}_per_s": round(rate, 1)
            for k, rate in self._rates.rates(now_ns, {k: counts[k] for k in RATE_COUNTS}).items()
        }
        commands = sup.commands
        age = "none" if commands.command_time is None else f"{now - commands.command_time:.3f} s"
        watchdog = sup.watchdog_status(p["watchdog_action"])
        values = {
            **rates,
            **{k: counts[k] for k in COMMAND_COUNTS},
            "watchdog": watchdog,
            "command_age": age,
            "command_timeout": p["command_timeout"],
            "max_goal_rate": p["max_goal_rate"],
            "phi_max": self._servos.limit.motor,
        }
        level = WARN if commands.state is Watchdog.EXPIRED else OK
        return Report(level, f"watchdog: {watchdog}", values)


def estop_report(servos: Servos, now: float) -> Report:
    """OK released; ERROR engaged."""
    estop = servos.sup.estop
    values = {
        "engaged": estop.reason is not None,
        "reason": estop.reason or "",
        "engaged_for": f"{now - estop.since:.1f} s" if estop.reason else "",
        "estops": servos.counts["estops"],
        "ignored_commands": servos.counts["ignored"],
    }
    if estop.reason is not None:
        return Report(ERROR, f"E-stop engaged ({estop.reason}): call clear_estop", values)
    return Report(OK, "released", values)


def add_statuses(
    diagnostics: Diagnostics, servos: Servos, p: dict[str, Any], now_ns: Callable[[], int]
) -> None:
    """Register the four statuses; ``now_ns`` is the node clock [ns]."""
    control = ControlReport(servos, p, now_ns())
    diagnostics.add("bus", lambda: bus_report(servos, p))
    diagnostics.add("servos", lambda: servo_report(servos, p))
    diagnostics.add("control", lambda: control(now_ns()))
    diagnostics.add("estop", lambda: estop_report(servos, now_ns() * 1e-9))

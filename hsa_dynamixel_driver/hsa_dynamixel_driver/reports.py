"""The dynamixel_driver's /diagnostics statuses (bus, servos, control, estop), built from the state of `Servos`.

Levels and values: docs/nodes/hsa_dynamixel_driver.md, section Diagnostics.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_core.rate_meter import RateMeter
from hsa_core.servo_supervision import Watchdog
from hsa_dynamixel_driver.bus import describe_hardware_error
from hsa_dynamixel_driver.servos import Servos

ERROR_COUNTS = ("bus_losses", "reconnect_attempts", "reconnects", "port_errors", "comm_errors", "status_errors")
COMMAND_COUNTS = ("commands", "rejected", "clamped", "rate_limited", "ignored")
RATE_COUNTS = ("cycles", "writes", "reads")


def bus_report(servos: Servos, p: dict[str, Any]) -> Report:
    """OK connected; WARN failures in a row or not configured; ERROR disconnected (with the reason)."""
    sup = servos.sup
    outage = "none" if sup.last_outage_s is None else f"{sup.last_outage_s:.3f} s"
    values = {"port": p["port"], "baudrate": p["baudrate"], "latency_timer": servos.latency,
              **{k: servos.counts[k] for k in ERROR_COUNTS},
              "last_outage": outage, "consecutive_failures": sup.consecutive_failures,
              "last_error": servos.last_error}
    if servos.bus is None:
        return Report(WARN, "not configured", values)
    if not sup.link_up:
        return Report(ERROR, f"disconnected: {sup.bus_problem}", values)
    return Report(WARN if sup.consecutive_failures else OK, "connected", values)


def servo_report(servos: Servos, p: dict[str, Any]) -> Report:
    """OK; WARN torque off on request or relaxed; ERROR torque wanted but refused, a hardware error, or the E-stop."""
    sup, limits = servos.sup, servos.limits
    values = {"torque": sup.note, "torque_on_failures_in_a_row": sup.torque_failures,
              "torque_retry_pending": sup.retry_at is not None,
              "neutral_ticks": list(servos.map.neutral_ticks) if servos.map else [],
              "neutral_source": p["neutral_source"],
              "goal_limits": [[int(lo), int(hi)] for lo, hi in zip(limits.lower, limits.upper)] if limits else [],
              "held_at_start": sup.held, "reboots": servos.counts["reboots"], "last_reboot": servos.last_reboot,
              **{f"hardware_error_{i}": describe_hardware_error(sup.hw_errors.get(i, 0)) for i in servos.ids}}
    if sup.hw_errors:
        return Report(ERROR, sup.hardware_problem() or "", values)
    if sup.estop is not None:
        return Report(ERROR, f"torque off: E-stop engaged ({sup.estop})", values)
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
        rates = {f"{k}_per_s": round(rate, 1)
                 for k, rate in self._rates.rates(now_ns, {k: counts[k] for k in RATE_COUNTS}).items()}
        age = "none" if sup.command_time is None else f"{now - sup.command_time:.3f} s"
        watchdog = sup.watchdog_status(p["watchdog_action"])
        values = {**rates, **{k: counts[k] for k in COMMAND_COUNTS},
                  "watchdog": watchdog, "command_age": age, "command_timeout": p["command_timeout"],
                  "max_goal_rate": p["max_goal_rate"], "phi_max": self._servos.limit.motor}
        return Report(WARN if sup.watchdog is Watchdog.EXPIRED else OK, f"watchdog: {watchdog}", values)


def estop_report(servos: Servos, now: float) -> Report:
    """OK released; ERROR engaged."""
    sup = servos.sup
    values = {"engaged": sup.estop is not None, "reason": sup.estop or "",
              "engaged_for": f"{now - sup.estop_since:.1f} s" if sup.estop else "",
              "estops": servos.counts["estops"], "ignored_commands": servos.counts["ignored"]}
    if sup.estop is not None:
        return Report(ERROR, f"E-stop engaged ({sup.estop}): call clear_estop", values)
    return Report(OK, "released", values)


def add_statuses(diagnostics: Diagnostics, servos: Servos, p: dict[str, Any], now_ns: Callable[[], int]) -> None:
    """Register the four statuses; ``now_ns`` is the node clock [ns]."""
    control = ControlReport(servos, p, now_ns())
    diagnostics.add("bus", lambda: bus_report(servos, p))
    diagnostics.add("servos", lambda: servo_report(servos, p))
    diagnostics.add("control", lambda: control(now_ns()))
    diagnostics.add("estop", lambda: estop_report(servos, now_ns() * 1e-9))

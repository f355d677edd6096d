"""controller_node's /diagnostics check "control loop": mode, tick rate, compute time and the loop's
counters."""

from __future__ import annotations

import numpy as np

from hsa_common.diagnostics import ERROR, OK, WARN, Report
from hsa_core.controller.control_loop import ControlLoop
from hsa_core.controller.supervision import Mode


class ControlReport:
    """Builds each period's report of a ControlLoop; remembers the rejections already reported (WARN
    on new ones)."""

    def __init__(self, loop: ControlLoop, controller: str, rate: float, scheduling: str) -> None:
        """Report on `loop`, running law `controller` at the nominal `rate` [Hz] under
        `scheduling` (in words)."""
        self._loop, self._controller, self._rate = loop, controller, rate
        self._scheduling = scheduling
        self._reported_rejections = 0

    def __call__(self, now_ns: int) -> Report:
        """Mode, tick rate and compute time over the period ending now, stale-input, driver and
        rejection counters."""
        loop = self._loop
        period = loop.period(now_ns)
        compute, rate = period.compute_s, period.rate_hz
        rejected = loop.rejections
        n_rejected = sum(rejected.states.values()) + loop.counters.rejected_setpoints
        new_rejections, self._reported_rejections = (
            n_rejected > self._reported_rejections,
            n_rejected,
        )
        age, silence = loop.supervisor.age_s(now_ns), loop.supervisor.driver_silence_s(now_ns)
        mode = loop.mode
        values = {
            "mode": mode.value,
            "estop": loop.supervisor.estop,
            "driver torque": "off" if loop.supervisor.torque_off else "on or not reported",
            "controller": self._controller,
            "tick rate [Hz]": f"{rate:.1f}",
            "nominal rate [Hz]": f"{self._rate:g}",
            "scheduling": self._scheduling,
            **vars(loop.counters),
            "pending_setpoints": loop.pending_setpoints,
            "rejected_states": sum(rejected.states.values()),
            **{f"rejected_states {reason}": n for reason, n in sorted(rejected.states.items())},
            **{
                f"rejected_setpoints {reason}": n
                for reason, n in sorted(rejected.setpoints.items())
            },
            "last_state_rejection": rejected.last_state,
            "last_setpoint_rejection": rejected.last_setpoint,
            "time_since_last_state [s]": f"{age:.3f}",
            "driver silence [s]": f"{silence:.3f}",
            "last_outage [s]": f"{loop.last_outage_s:.3f}",
            "e_int": np.round(loop.controller.state.e_int, 6).tolist(),
            "compute time mean [ms]": f"{1e3 * np.mean(compute):.3f}" if compute else "-",
            "compute time max [ms]": f"{1e3 * np.max(compute):.3f}" if compute else "-",
        }
        if mode is Mode.ESTOP:
            return Report(ERROR, "E-STOP: no command is sent", values)
        if mode is Mode.DRIVER_LOST:
            return Report(
                ERROR,
                f"driver lost: no phi_present for {silence:.3g} s, no command is sent, integrators "
                "frozen",
                values,
            )
        if mode is Mode.TORQUE_OFF:
            return Report(
                ERROR, "driver torque off: no command is sent, integrators frozen", values
            )
        if mode is Mode.STALE:
            return Report(ERROR, f"stale: newest state {age:.3g} s old, no command is sent", values)
        if mode is Mode.HOLD:
            return Report(
                WARN, f"stale: newest state {age:.3g} s old, holding the last command", values
            )
        if mode is not Mode.TRACKING:
            return Report(WARN, mode.value, values)
        if rate < 0.9 * self._rate:
            return Report(
                WARN, f"tracking, tick rate {rate:.1f} Hz below 90 % of {self._rate:g} Hz", values
            )
        if new_rejections:
            return Report(WARN, "tracking; inputs were rejected in this period", values)
        return Report(OK, "tracking", values)

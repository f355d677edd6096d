"""controller_node: one control law of planning_and_control.md §3 at a fixed rate, with the supervision of §5.

Every input is checked before it can reach the law (hsa_core.validation): a setpoint must be plausible and an
equilibrium of the model under its own phi^ss (static residual at q^d within `setpoint_residual_tol`, chiee^d = FK(q^d)
within `setpoint_pose_tol`, 0 <= optimality error <= 1e-3); a refused one leaves the previous one active. A state must
have plausible magnitudes and a stamp newer than the newest accepted one. Refusals are counted on /diagnostics and
logged at most once per `rejection_log_period`.

The mode of each tick is decided by hsa_core.supervision.Supervisor, fed by this node with the node clock (the clock
of the state stamps): E-stop (latched `estop` true) -> nothing is sent, the integrators were reset; no setpoint, no
driver heartbeat (`phi_present`) within `driver_timeout`, or no usable state -> nothing is sent; a state whose stamp
is older than `stale_timeout` -> the last command is re-published unchanged and the controller is not stepped (no
integral wind-up) for at most `hold_timeout`, after which nothing is sent (the driver's command watchdog holds the
motors); otherwise the controller steps and `phi_cmd` is published. From the first tracking tick on,
`controller_info` reports every tick. The math is hsa_core.control's Controller, compiled in the constructor; the
integrators use dt = 1/rate and stay finite by construction (Controller.step).
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.time import Time
from std_msgs.msg import Bool

from hsa_common import qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates
from hsa_common.runner import run, seconds
from hsa_core.actuation import MotorMap
from hsa_core.control import CollocatedGains, Controller, ControllerKind, EeIntegralGains, PidGains, default_gains
from hsa_core.planning import MAX_OPTIMALITY_ERROR
from hsa_core.planning import Setpoint as CoreSetpoint
from hsa_core.supervision import Action, Mode, Supervisor, SupervisorConfig
from hsa_core.validation import POSE_TOLERANCE, SetpointValidator, q_bounds, state_problem
from hsa_msgs.msg import ControllerInfo, CsConfiguration, PlanarActuation, PlanarPose, PlanarState, Setpoint
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_core.jaxsetup import configure_jax

FRAME_ID = "hsa_base"
DEADLINE_FACTOR = 1.5
"""A tick that starts more than 1.5 periods after the previous one counts as a deadline miss."""

_COLLOCATED = default_gains(ControllerKind.PSATID)
_PID = default_gains(ControllerKind.PID)
_EE = EeIntegralGains()


def _positive(value: Any) -> str | None:
    """Strictly positive (ranges only give >= 0)."""
    return None if value > 0.0 else f"must be > 0, got {value!r}"


SPECS = (
    *MODEL_SPECS,
    ParamSpec("controller", ControllerKind.PSATID.value, "control law: P-satI-D, P-satI-D + gravity cancellation or "
              "the task-space PID baseline", choices=tuple(k.value for k in ControllerKind), read_only=True),
    ParamSpec("rate", 40.0, "[Hz] control rate; the integrators use dt = 1/rate", low=1.0, high=1000.0,
              read_only=True),
    ParamSpec("kp", _COLLOCATED.kp, "[rad^2/(N m)] P-satI-D(+GC) proportional gain", low=0.0, high=100.0),
    ParamSpec("ki", _COLLOCATED.ki, "[rad/s] P-satI-D(+GC) integral gain", low=0.0, high=100.0),
    ParamSpec("kd", _COLLOCATED.kd, "[rad^2 s/(N m)] P-satI-D(+GC) derivative gain", low=0.0, high=100.0),
    ParamSpec("gamma", _COLLOCATED.gamma, "[rad/(N m)] P-satI-D(+GC) tanh compression of the integrand (> 0)",
              low=0.0, high=1e5, validator=_positive),
    ParamSpec("kp_pid", _PID.kp, "[rad/m] task-space PID proportional gain", low=0.0, high=1e4),
    ParamSpec("ki_pid", _PID.ki, "[rad/(m s)] task-space PID integral gain", low=0.0, high=1e5),
    ParamSpec("kd_pid", _PID.kd, "[rad s/m] task-space PID derivative gain", low=0.0, high=1e3),
    ParamSpec("reset_integral_on_setpoint_change", False, "zero e_int when a new setpoint is accepted"),
    ParamSpec("ee_integral", False, "EE-position integral extension (§3.8; collocated laws only)", read_only=True),
    ParamSpec("ee_ki", _EE.ki_ee, "[1/s] EE-integral gain K_I,ee (time constant >= 3 s recommended)",
              low=0.0, high=100.0),
    ParamSpec("ee_e_on", _EE.e_on, "[m] EE integral runs only while |p^d - p_ee| is below this (> 0)",
              low=0.0, high=0.1, validator=_positive),
    ParamSpec("ee_z_max", _EE.z_max, "[m s] clamp of each EE integral state", low=0.0, high=1.0),
    ParamSpec("ee_reset_on_setpoint_change", _EE.reset_on_setpoint_change,
              "zero the EE integral state when a new setpoint is accepted", read_only=True),
    ParamSpec("stale_timeout", 0.1, "[s] a state whose stamp is older than this (node clock) is stale: hold the last "
              "command; states stamped more than this in the future are refused", low=0.001, high=10.0,
              read_only=True),
    ParamSpec("hold_timeout", 0.25, "[s] stop re-publishing the held command once the newest state is this old "
              "(>= stale_timeout)", low=0.001, high=60.0, read_only=True),
    ParamSpec("stamp_clock", True, "state stamps are on the node clock (age judged by stamp); false only where they "
              "are not, e.g. replayed recorded stamps (age then judged by arrival)", read_only=True),
    ParamSpec("driver_timeout", 0.25, "[s] no phi_present from the driver for this long: driver lost, nothing is "
              "sent, integrators frozen; 0 = no driver in this graph (replay, controller-only tests)",
              low=0.0, high=10.0, read_only=True),
    ParamSpec("setpoint_residual_tol", MAX_OPTIMALITY_ERROR, "[N m, N] largest ||G + K - alpha|| at (q_des, phi_ss) "
              "of an accepted setpoint (the planner's acceptance threshold)", low=1e-12, high=1.0, read_only=True),
    ParamSpec("setpoint_pose_tol", POSE_TOLERANCE, "[m, rad] largest |chiee_des - FK(q_des)| of an accepted "
              "setpoint", low=1e-12, high=0.1, read_only=True),
    ParamSpec("rejection_log_period", 5.0, "[s] refused setpoints and states are logged at most once per period "
              "(all are counted on /diagnostics)", low=0.0, high=3600.0, read_only=True),
    ParamSpec("diagnostics_period", 1.0, "[s] period of the /diagnostics reports", low=0.05, high=60.0,
              read_only=True),
)
GAIN_NAMES = ("kp", "ki", "kd", "gamma", "kp_pid", "ki_pid", "kd_pid", "ee_ki", "ee_e_on", "ee_z_max")

INFO_STATE = {
    Mode.WAITING_FOR_SETPOINT: ControllerInfo.STATE_WAITING_FOR_SETPOINT, Mode.TRACKING: ControllerInfo.STATE_TRACKING,
    Mode.HOLD: ControllerInfo.STATE_HOLD_STALE, Mode.ESTOP: ControllerInfo.STATE_STOPPED,
    **{m: ControllerInfo.STATE_WAITING_FOR_STATE
       for m in (Mode.WAITING_FOR_DRIVER, Mode.WAITING_FOR_STATE, Mode.STALE, Mode.DRIVER_LOST)},
}
"""controller_info state of each mode (hsa_msgs has no driver constants: those ticks send nothing, as WAITING_FOR_STATE)."""
NOTHING_SENT = np.full(2, math.nan)
"""φ fields of the info on ticks that send no command."""


class ControllerNode(Node):
    """Runs the selected law on a timer; publishes phi_cmd and controller_info; reports on /diagnostics."""

    def __init__(self) -> None:
        """Declare and validate parameters, build and compile the controller and the checks, then start the timer."""
        super().__init__("controller_node")
        self._p = declare(self, SPECS)
        if self._p["hold_timeout"] < self._p["stale_timeout"]:
            raise ParameterValidationError(
                f"parameter 'hold_timeout' ({self._p['hold_timeout']} s) must be >= stale_timeout "
                f"({self._p['stale_timeout']} s)")
        self._kind = ControllerKind(self._p["controller"])
        if self._p["ee_integral"] and self._kind is ControllerKind.PID:
            raise ParameterValidationError("parameter 'ee_integral' applies to the collocated laws only, not 'pid'")
        params = load_model(self._p)
        self._controller = Controller(
            self._kind, params, self._gains(self._p), dt=1.0 / self._p["rate"],
            ee_integral=self._ee_gains(self._p) if self._p["ee_integral"] else None,
            reset_integral_on_setpoint_change=self._p["reset_integral_on_setpoint_change"],
        )
        self._validator = SetpointValidator(params, self._p["setpoint_residual_tol"], self._p["setpoint_pose_tol"])
        self._q_bounds = q_bounds(params)
        self._supervisor = Supervisor(SupervisorConfig(
            self._p["stale_timeout"], self._p["hold_timeout"], self._p["driver_timeout"], self._p["stamp_clock"]))
        guard_updates(self, SPECS, self._apply)
        self._motor_map = MotorMap(h=tuple(int(v) for v in np.asarray(params.h)))
        self._period = 1.0 / self._p["rate"]
        self._state: PlanarState | None = None  # the newest usable state (plausible, velocity_valid, newest stamp)
        self._setpoint_msg: Setpoint | None = None
        self._last_cmd: PlanarActuation | None = None
        self._last_info: ControllerInfo | None = None  # info of the newest tracking tick
        self._mode = Mode.WAITING_FOR_SETPOINT
        self._decision_age = math.nan  # state age [s] at the newest tick
        self._driver_silence = math.nan  # driver silence [s] at the newest tick
        self._last_tick: Time | None = None
        self._tracked_at: Time | None = None  # newest tracking tick
        self._lost_at: Time | None = None  # last tracking tick before the current outage (None while tracking)
        self._last_outage = math.nan
        self._stats = {"ticks": 0, "deadline_misses": 0, "stale_events": 0, "held_ticks": 0, "stale_stops": 0,
                       "estop_events": 0, "driver_lost_events": 0, "refused_ticks": 0, "saturated": 0,
                       "setpoints": 0, "rejected_setpoints": 0}
        self._incoming: list[Setpoint] = []  # received setpoints not yet active
        self._rejected_states: Counter[str] = Counter()
        self._rejected_setpoints: Counter[str] = Counter()
        self._rejections = {"state": "-", "setpoint": "-"}
        self._reported_rejections = 0
        self._window: dict[str, Any] = {"ticks": 0, "compute": [], "start": self.get_clock().now()}
        self._cmd_pub = self.create_publisher(PlanarActuation, "phi_cmd", qos.COMMAND,
                                              qos_overriding_options=qos.overridable())
        self._info_pub = self.create_publisher(ControllerInfo, "controller_info", qos.INFO,
                                               qos_overriding_options=qos.overridable())
        self.create_subscription(PlanarState, "state", self._on_state, qos.SENSOR,
                                 qos_overriding_options=qos.overridable())
        self.create_subscription(Setpoint, "setpoint", self._on_setpoint, qos.LATCHED,
                                 qos_overriding_options=qos.overridable())
        self.create_subscription(Bool, "estop", self._on_estop, qos.LATCHED, qos_overriding_options=qos.overridable())
        if self._p["driver_timeout"] > 0.0:
            self.create_subscription(PlanarActuation, "phi_present", self._on_driver, qos.SENSOR,
                                     qos_overriding_options=qos.overridable())
        self.create_timer(self._period, self._tick)
        diagnostics = Diagnostics(self, self._p["diagnostics_period"])
        diagnostics.add("control loop", self._report)
        driver = (f"watching the driver (timeout {self._p['driver_timeout']:g} s)" if self._p["driver_timeout"] > 0.0
                  else "no driver in this graph")
        self.get_logger().info(f"'{self._kind.value}' at {self._p['rate']:g} Hz, {driver}, waiting for setpoint")

    def _gains(self, v: dict[str, Any]) -> CollocatedGains | PidGains:
        """Gains of the selected law from parameter values."""
        if self._kind is ControllerKind.PID:
            return PidGains(kp=v["kp_pid"], ki=v["ki_pid"], kd=v["kd_pid"])
        return CollocatedGains(kp=v["kp"], ki=v["ki"], kd=v["kd"], gamma=v["gamma"])

    @staticmethod
    def _ee_gains(v: dict[str, Any]) -> EeIntegralGains:
        """EE-integral gains from parameter values."""
        return EeIntegralGains(ki_ee=v["ee_ki"], e_on=v["ee_e_on"], z_max=v["ee_z_max"],
                               reset_on_setpoint_change=v["ee_reset_on_setpoint_change"])

    def _apply(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time updates to the running controller; the integrator state is kept."""
        if not changes:
            return
        self._p.update(changes)
        if any(name in GAIN_NAMES for name in changes):
            self._controller.gains = self._gains(self._p)
            if self._controller.ee_integral is not None:
                self._controller.ee_integral = self._ee_gains(self._p)
        self._controller.reset_integral_on_setpoint_change = self._p["reset_integral_on_setpoint_change"]
        self.get_logger().info(f"parameters updated: {changes}")

    def _now_ns(self) -> int:
        """Node clock [ns], the clock of the state stamps."""
        return self.get_clock().now().nanoseconds

    def _on_driver(self, _msg: PlanarActuation) -> None:
        """A phi_present sample: the driver is alive."""
        self._supervisor.driver_heartbeat(self._now_ns())

    def _on_state(self, msg: PlanarState) -> None:
        """Keep the newest usable state: plausible magnitudes, velocity_valid, stamp newer than the newest and not in
        the future; refusals are counted and logged at most once per rejection_log_period."""
        problem = state_problem(self._q_bounds, _q(msg.q), _q(msg.q_dot), _pose(msg.chiee), _pose(msg.chiee_dot),
                                msg.velocity_valid)
        if problem is None and msg.velocity_valid:
            problem = self._supervisor.state(Time.from_msg(msg.header.stamp).nanoseconds, self._now_ns())
            if problem is None:
                self._state = msg
                return
        if problem is not None:
            reason = problem.split(":")[0]
            self._rejected_states[reason] += 1
            self._rejections["state"] = problem
            self.get_logger().warning(f"rejected state: {problem} ({sum(self._rejected_states.values())} so far)",
                                      throttle_duration_sec=self._p["rejection_log_period"])

    def _on_setpoint(self, msg: Setpoint) -> None:
        """Queue a setpoint; the first tick after its stamp activates it (``_activate``)."""
        self._incoming.append(msg)

    def _activate_setpoints(self, now_ns: int) -> None:
        """Activate the queued setpoints stamped before this tick, in order: a tick at the very instant a setpoint
        was stamped still uses the previous one, whichever arrived first (deterministic under simulated time)."""
        while self._incoming and Time.from_msg(self._incoming[0].header.stamp).nanoseconds < now_ns:
            self._activate(self._incoming.pop(0))

    def _activate(self, msg: Setpoint) -> None:
        """Activate a setpoint after the physical checks; a refused one leaves the previous active."""
        setpoint = CoreSetpoint(
            np.array([msg.chiee_des.x, msg.chiee_des.y, msg.chiee_des.theta]),
            np.array([msg.q_des.kappa_be, msg.q_des.sigma_sh, msg.q_des.sigma_ax]),
            np.asarray(msg.phi_ss, dtype=np.float64), msg.optimality_error,
        )
        problem = self._validator.problem(setpoint)
        if problem is None:
            try:
                self._controller.set_setpoint(setpoint)
            except ValueError as exc:
                problem = str(exc)
        if problem is not None:
            self._stats["rejected_setpoints"] += 1
            self._rejected_setpoints[problem.split(":")[0]] += 1
            self._rejections["setpoint"] = problem
            kept = "keeping the previous setpoint" if self._setpoint_msg is not None else "no setpoint active"
            self.get_logger().warning(
                f"rejected setpoint {msg.trajectory_index}: {problem}; {kept} "
                f"({self._stats['rejected_setpoints']} rejected so far)",
                throttle_duration_sec=self._p["rejection_log_period"])
            return
        self._setpoint_msg = msg
        self._supervisor.setpoint_accepted()
        self._stats["setpoints"] += 1
        self.get_logger().debug(f"setpoint {msg.trajectory_index}/{msg.trajectory_length} active")

    def _on_estop(self, msg: Bool) -> None:
        """E-stop state from the driver: on entry the integrators are reset and the held command is dropped."""
        if bool(msg.data) == self._supervisor.estop:
            return
        if self._supervisor.set_estop(bool(msg.data)):
            self._controller.reset()
            self._last_cmd = None
            self._stats["estop_events"] += 1
            self.get_logger().error("E-STOP: no phi_cmd is sent, integrators reset")
        else:
            self.get_logger().warning("E-stop cleared: resuming from a fresh controller state (integrators zero)")

    def _tick(self) -> None:
        """One control period: the supervisor decides; step and publish, re-publish the held command, or send nothing."""
        now = self.get_clock().now()
        self._count_tick(now)
        self._activate_setpoints(now.nanoseconds)
        decision = self._supervisor.tick(now.nanoseconds)
        self._decision_age, self._driver_silence = decision.age_s, decision.driver_silence_s
        if decision.action is Action.STEP:
            if self._step(now, self._state):
                self._set_mode(decision.mode, now)
            else:  # refused by the core (counted): nothing is sent this tick
                self._publish_info(now, ControllerInfo.STATE_WAITING_FOR_STATE, commanded=False)
        elif decision.action is Action.HOLD and self._last_cmd is not None:
            self._set_mode(decision.mode, now)
            self._hold(now)
        else:
            mode = Mode.STALE if decision.action is Action.HOLD else decision.mode  # nothing to hold
            self._set_mode(mode, now)
            self._publish_info(now, INFO_STATE[mode], commanded=False)

    def _step(self, now: Time, state: PlanarState) -> bool:
        """Step the controller on the state and publish the command and the tick's info; False if the core refused."""
        t0 = time.perf_counter()
        try:
            phi, info = self._controller.step(
                _q(state.q), _q(state.q_dot), _pose(state.chiee), _pose(state.chiee_dot))
        except ValueError as exc:
            self._stats["refused_ticks"] += 1
            self.get_logger().error(f"tick refused: {exc}", throttle_duration_sec=self._p["rejection_log_period"])
            return False
        compute_time = time.perf_counter() - t0
        self._window["compute"].append(compute_time)
        self._stats["saturated"] += int(info.saturated)
        stamp = now.to_msg()
        cmd = PlanarActuation(phi=np.asarray(phi, dtype=np.float64))
        cmd.header.stamp, cmd.header.frame_id = stamp, FRAME_ID
        cmd.source_stamp = state.header.stamp
        out = ControllerInfo(
            state_stamp=state.header.stamp, controller=self._kind.value, state=ControllerInfo.STATE_TRACKING,
            setpoint=self._setpoint_msg, chiee=_pose_msg(info.chiee), chiee_des=_pose_msg(info.chiee_des),
            q=_q_msg(info.q), q_des=_q_msg(info.q_des), q_dot=state.q_dot, varphi=info.varphi,
            varphi_des=info.varphi_des, e_int=info.e_int, z_ee=info.z_ee, phi_ss=info.phi_ss,
            phi_des_unsat=info.phi_des_unsat, phi_des_sat=info.phi_des_sat,
            motor_goal_angles=self._motor_map.motor_angles(phi), saturated=bool(info.saturated),
            state_age=(now - Time.from_msg(state.header.stamp)).nanoseconds * 1e-9, compute_time=compute_time,
        )
        out.header.stamp, out.header.frame_id = stamp, FRAME_ID
        self._cmd_pub.publish(cmd)
        self._info_pub.publish(out)
        self._last_cmd, self._last_info, self._tracked_at = cmd, out, now
        return True

    def _hold(self, now: Time) -> None:
        """Re-publish the last command (same phi and source stamp); the controller is not stepped."""
        self._stats["held_ticks"] += 1
        self._last_cmd.header.stamp = now.to_msg()
        self._cmd_pub.publish(self._last_cmd)
        self._publish_info(now, ControllerInfo.STATE_HOLD_STALE, commanded=True)

    def _publish_info(self, now: Time, state: int, commanded: bool) -> None:
        """Info of a tick without a controller step: the last tracking tick's fields with this tick's state, stamp,
        setpoint and integrator state; φ fields NaN when nothing is sent. Nothing before the first tracking tick."""
        if self._last_info is None:
            return
        info = copy.deepcopy(self._last_info)
        info.header.stamp, info.state, info.compute_time = now.to_msg(), state, 0.0
        info.setpoint = self._setpoint_msg
        info.state_age = (now - Time.from_msg(info.state_stamp)).nanoseconds * 1e-9
        integrators = self._controller.state
        info.e_int, info.z_ee = integrators.e_int, integrators.z_ee
        if not commanded:
            info.phi_des_unsat, info.phi_des_sat = NOTHING_SENT, NOTHING_SENT
            info.motor_goal_angles = np.full(4, math.nan)
            info.saturated = False
        self._info_pub.publish(info)

    def _set_mode(self, mode: Mode, now: Time) -> None:
        """Record the mode; log changes once (INFO back to tracking, WARN entering the hold, ERROR when commands stop
        for missing states or a lost driver)."""
        if mode == self._mode:
            return
        old, self._mode = self._mode, mode
        text = f"{old.value} -> {mode.value}"
        if old is Mode.TRACKING:
            self._lost_at = self._tracked_at
        if mode is Mode.TRACKING:
            if self._lost_at is not None:
                self._last_outage, self._lost_at = seconds(now - self._lost_at), None
                text += f" after {self._last_outage:.3f} s without tracking"
            self.get_logger().info(text)
        elif mode is Mode.HOLD:
            self._stats["stale_events"] += 1
            self.get_logger().warning(f"{text}: newest state {self._decision_age:.3f} s old; re-publishing the last "
                                      "command, integrators frozen")
        elif mode is Mode.STALE:
            self._stats["stale_stops"] += 1
            self.get_logger().error(f"{text}: newest state {self._decision_age:.3f} s old; no command is sent (the "
                                    "driver's watchdog holds the motors), integrators frozen")
        elif mode is Mode.DRIVER_LOST:
            self._stats["driver_lost_events"] += 1
            self.get_logger().error(f"{text}: no phi_present from the driver for {self._driver_silence:.3f} s; no "
                                    "command is sent, integrators frozen until it returns")
        else:  # start-up, and E-stop changes (logged as ERROR/WARN when the estop message arrives)
            self.get_logger().info(text)

    def _count_tick(self, now: Time) -> None:
        """Tick counters and deadline misses (tick interval > DEADLINE_FACTOR periods)."""
        if self._last_tick is not None and (now - self._last_tick).nanoseconds * 1e-9 > DEADLINE_FACTOR * self._period:
            self._stats["deadline_misses"] += 1
        self._last_tick = now
        self._stats["ticks"] += 1
        self._window["ticks"] += 1

    def _report(self) -> Report:
        """Mode, tick rate and compute time over the last period, stale-input, driver and rejection counters."""
        now = self.get_clock().now()
        elapsed = (now - self._window["start"]).nanoseconds * 1e-9
        compute = self._window["compute"]
        rate = self._window["ticks"] / elapsed if elapsed > 0.0 else 0.0
        self._window = {"ticks": 0, "compute": [], "start": now}
        rejections = sum(self._rejected_states.values()) + self._stats["rejected_setpoints"]
        new_rejections, self._reported_rejections = rejections > self._reported_rejections, rejections
        age = self._supervisor.age_s(now.nanoseconds)
        silence = self._supervisor.driver_silence_s(now.nanoseconds)
        values = {
            "mode": self._mode.value, "estop": self._supervisor.estop, "controller": self._kind.value,
            "tick rate [Hz]": f"{rate:.1f}", "nominal rate [Hz]": f"{self._p['rate']:g}", **self._stats,
            "rejected_states": sum(self._rejected_states.values()),
            **{f"rejected_states {reason}": n for reason, n in sorted(self._rejected_states.items())},
            **{f"rejected_setpoints {reason}": n for reason, n in sorted(self._rejected_setpoints.items())},
            "last_state_rejection": self._rejections["state"],
            "last_setpoint_rejection": self._rejections["setpoint"],
            "time_since_last_state [s]": f"{age:.3f}", "driver silence [s]": f"{silence:.3f}",
            "last_outage [s]": f"{self._last_outage:.3f}",
            "e_int": np.round(self._controller.state.e_int, 6).tolist(),
            "compute time mean [ms]": f"{1e3 * np.mean(compute):.3f}" if compute else "-",
            "compute time max [ms]": f"{1e3 * np.max(compute):.3f}" if compute else "-",
        }
        if self._mode is Mode.ESTOP:
            return Report(ERROR, "E-STOP: no command is sent", values)
        if self._mode is Mode.DRIVER_LOST:
            return Report(ERROR, f"driver lost: no phi_present for {silence:.3g} s, no command is sent, integrators "
                                 "frozen", values)
        if self._mode is Mode.STALE:
            return Report(ERROR, f"stale: newest state {age:.3g} s old, no command is sent", values)
        if self._mode is Mode.HOLD:
            return Report(WARN, f"stale: newest state {age:.3g} s old, holding the last command", values)
        if self._mode is not Mode.TRACKING:
            return Report(WARN, self._mode.value, values)
        if rate < 0.9 * self._p["rate"]:
            return Report(WARN, f"tracking, tick rate {rate:.1f} Hz below 90 % of {self._p['rate']:g} Hz", values)
        if new_rejections:
            return Report(WARN, "tracking; inputs were rejected in this period", values)
        return Report(OK, "tracking", values)


def _q(msg: CsConfiguration) -> np.ndarray:
    """[kappa_be, sigma_sh, sigma_ax] of a CsConfiguration."""
    return np.array([msg.kappa_be, msg.sigma_sh, msg.sigma_ax])


def _pose(msg: PlanarPose) -> np.ndarray:
    """[x, y, theta] of a PlanarPose."""
    return np.array([msg.x, msg.y, msg.theta])


def _q_msg(q: np.ndarray) -> CsConfiguration:
    """CsConfiguration of [kappa_be, sigma_sh, sigma_ax]."""
    return CsConfiguration(kappa_be=float(q[0]), sigma_sh=float(q[1]), sigma_ax=float(q[2]))


def _pose_msg(chiee: np.ndarray) -> PlanarPose:
    """PlanarPose of [x, y, theta]."""
    return PlanarPose(x=float(chiee[0]), y=float(chiee[1]), theta=float(chiee[2]))


def main() -> None:
    """Console script `controller_node`."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(ControllerNode, "controller_node"))

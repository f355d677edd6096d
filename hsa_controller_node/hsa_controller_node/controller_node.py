"""controller_node: one control law of planning_and_control.md §3 at a fixed rate, with the
supervision of §5.

Every input is checked before it can reach the law (hsa_core.controller.validation): a setpoint must
be plausible and an equilibrium of the model under its own phi^ss (static residual at q^d within
`setpoint_residual_tol`, chiee^d = FK(q^d) within `setpoint_pose_tol`, 0 <= optimality error <=
1e-3); a refused one leaves the previous one active. A state must have plausible magnitudes and a
stamp newer than the newest accepted one. Refusals are counted on /diagnostics and logged at most
once per `rejection_log_period`.

Every decision of a tick is hsa_core.controller.control_loop.ControlLoop (the offline experiment
runs the same one), around the mode state machine hsa_core.controller.supervision.Supervisor, fed by
this node with the node clock (the clock of the state stamps): E-stop (latched `estop` true) ->
nothing is sent, the integrators were reset; no setpoint, no driver heartbeat (`phi_present`) within
`driver_timeout`, the driver's servos without torque (latched `torque` false), or no usable state ->
nothing is sent; a state whose stamp is older than `stale_timeout` -> the last command is
re-published unchanged and the controller is not stepped (no integral wind-up) for at most
`hold_timeout`, after which nothing is sent (the driver's command watchdog holds the motors);
otherwise the controller steps and `phi_cmd` is published. From the first tracking tick on,
`controller_info` reports every tick. A setpoint costs O(1) on arrival (its serialized message is
kept, at most SETPOINT_INTAKE of them); the tick decodes the kept ones and checks at most a few, the
newest winning (hsa_core.controller.control_loop), so a setpoint flood cannot stall the tick. With
`realtime_priority` > 0 every thread runs under SCHED_RR once the node is built
(hsa_controller_node.scheduling), so busy processes cannot keep the tick waiting for a CPU either.
The math is hsa_core.controller.control's Controller, compiled in the constructor; the integrators
use dt = 1/rate (or `integrator_dt`) and stay finite by construction (Controller.step). With
`velocity_estimator` smoothing_spline_16 (the September 2023 stand-in,
hsa_core.sim.run_conditions.TickEstimator) the rates of the states are not used: each tick fits them
to the newest state of the last 16 ticks. This node only declares parameters, converts messages,
publishes and logs.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
from rclpy._rclpy_pybind11 import RMWError
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.time import Time
from std_msgs.msg import Bool

from hsa_common import convert, qos
from hsa_common.diagnostics import Diagnostics
from hsa_common.model_params import load_model, load_wiring_param
from hsa_common.parameters import declare, guard_updates
from hsa_common.runner import run
from hsa_controller_node import scheduling
from hsa_controller_node.messages import INFO_STATE, command_msg, repeated_info, tracking_info
from hsa_controller_node.parameters import SPECS, check_combination, ee_gains, gains, tuning
from hsa_controller_node.report import ControlReport
from hsa_core.controller.control import Controller, ControllerKind, retune
from hsa_core.controller.control_loop import SETPOINT_INTAKE, ControlLoop, Tick
from hsa_core.controller.supervision import Action, Mode, Supervisor, SupervisorConfig
from hsa_core.controller.validation import SetpointValidator
from hsa_core.jaxsetup import configure_jax
from hsa_core.runs.profiles import VelocityEstimator
from hsa_core.sim.run_conditions import TickEstimator
from hsa_core.task.planning import Setpoint as CoreSetpoint
from hsa_msgs.msg import ControllerInfo, PlanarActuation, PlanarState, Setpoint


class ControllerNode(Node):
    """Runs the selected law on a timer; publishes phi_cmd and controller_info; reports on
    /diagnostics."""

    def __init__(self) -> None:
        """Declare and validate parameters, build and compile the controller and the checks, then
        start the timer."""
        super().__init__("controller_node")
        p = self._p = declare(self, SPECS)
        check_combination(p)
        self._kind = ControllerKind(p["controller"])
        params = load_model(p)
        controller = Controller(
            self._kind,
            params,
            gains(self._kind, p),
            dt=p["integrator_dt"] or 1.0 / p["rate"],
            ee_integral=ee_gains(p) if p["ee_integral"] else None,
            reset_integral_on_setpoint_change=p["reset_integral_on_setpoint_change"],
        )
        validator = SetpointValidator(params, p["setpoint_residual_tol"], p["setpoint_pose_tol"])
        supervisor = Supervisor(
            SupervisorConfig(
                p["stale_timeout"], p["hold_timeout"], p["driver_timeout"], p["stamp_clock"]
            )
        )
        self._loop = ControlLoop(controller, supervisor, self._now_ns(), check=validator.problem)
        guard_updates(self, SPECS, self._apply)
        # motor_goal_angles, as the driver maps
        self._motor_map = load_wiring_param(p["wiring_file"]).motor_map(params)
        self._last_info: ControllerInfo | None = None  # info of the newest tracking tick
        # serialized setpoints received since the last tick, newest last
        self._setpoints: deque[bytes] = deque()
        self._tick_estimator = (
            TickEstimator(1.0 / p["rate"])
            if VelocityEstimator(p["velocity_estimator"]) is VelocityEstimator.SMOOTHING_SPLINE_16
            else None
        )
        # stamp, q, chiee: for the tick estimator
        self._newest: tuple[int, np.ndarray, np.ndarray] | None = None
        self._cmd_pub = self.create_publisher(
            PlanarActuation, "phi_cmd", qos.COMMAND, qos_overriding_options=qos.overridable()
        )
        self._info_pub = self.create_publisher(
            ControllerInfo, "controller_info", qos.INFO, qos_overriding_options=qos.overridable()
        )
        self.create_subscription(
            PlanarState,
            "state",
            self._on_state,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(
            Setpoint,
            "setpoint",
            self._on_setpoint,
            qos.LATCHED,
            raw=True,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(
            Bool, "estop", self._on_estop, qos.LATCHED, qos_overriding_options=qos.overridable()
        )
        if p["driver_timeout"] > 0.0:
            self.create_subscription(
                PlanarActuation,
                "phi_present",
                self._on_driver,
                qos.SENSOR,
                qos_overriding_options=qos.overridable(),
            )
            self.create_subscription(
                Bool,
                "torque",
                self._on_torque,
                qos.LATCHED,
                qos_overriding_options=qos.overridable(),
            )
        self.create_timer(1.0 / p["rate"], self._tick)
        policy = scheduling.describe(p["realtime_priority"])
        report = ControlReport(self._loop, self._kind.value, p["rate"], policy)
        Diagnostics(self, p["diagnostics_period"]).add(
            "control loop", lambda: report(self._now_ns())
        )
        if p["realtime_priority"] > 0:  # built and compiled: every thread from now on, and new ones
            scheduling.apply(p["realtime_priority"])
        driver = (
            f"watching the driver (timeout {p['driver_timeout']:g} s)"
            if p["driver_timeout"] > 0.0
            else "no driver in this graph"
        )
        self.get_logger().info(
            f"'{self._kind.value}' at {p['rate']:g} Hz, {driver}, "
            f"scheduling {policy}, waiting for setpoint"
        )

    def on_shutdown(self) -> None:
        """Before the runner's teardown: back to normal scheduling (the runner then lowers it
        further, so that in a graph stop the driver's torque-off never waits behind this node)."""
        if self._p["realtime_priority"] > 0:
            scheduling.apply(0)

    def _apply(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time updates to the running controller; the integrator state is
        kept."""
        if not changes:
            return
        self._p.update(changes)
        retune(self._loop.controller, tuning(self._kind, self._p))
        self.get_logger().info(f"parameters updated: {changes}")

    def _now_ns(self) -> int:
        """Node clock [ns], the clock of the state stamps."""
        return self.get_clock().now().nanoseconds

    def _on_driver(self, _msg: PlanarActuation) -> None:
        """A phi_present sample: the driver is alive."""
        self._loop.heartbeat(self._now_ns())

    def _on_torque(self, msg: Bool) -> None:
        """The driver's torque state: while off, nothing is sent and the integrators are frozen
        (mode torque off)."""
        on = bool(msg.data)
        if self._loop.driver_torque(on):
            self.get_logger().info(
                "driver reports torque on" if on else "driver reports torque off"
            )

    def _on_state(self, msg: PlanarState) -> None:
        """Hand a state to the loop (plausible, velocity_valid, newest stamp, not in the future);
        refusals are logged at most once per rejection_log_period. With the tick estimator, keep it
        for the next tick instead."""
        stamp, q = convert.stamp_ns(msg.header.stamp), convert.configuration(msg.q)
        chiee = convert.planar_pose(msg.chiee)
        if self._tick_estimator is not None:
            self._newest = stamp, q, chiee
            return
        self._hand_state(
            stamp,
            q,
            convert.configuration(msg.q_dot),
            chiee,
            convert.planar_pose(msg.chiee_dot),
            msg.velocity_valid,
        )

    def _hand_state(
        self,
        stamp: int,
        q: np.ndarray,
        q_dot: np.ndarray,
        chiee: np.ndarray,
        chiee_dot: np.ndarray,
        valid: bool,
    ) -> None:
        """Give a state to the loop; log a refusal (throttled)."""
        problem = self._loop.state(stamp, self._now_ns(), q, q_dot, chiee, chiee_dot, valid)
        if problem is not None:
            self.get_logger().warning(
                f"rejected state: {problem} ({sum(self._loop.rejections.states.values())} so far)",
                throttle_duration_sec=self._p["rejection_log_period"],
            )

    def _on_setpoint(self, raw: bytes) -> None:
        """Keep a serialized setpoint for the next tick, O(1); beyond SETPOINT_INTAKE the oldest is
        superseded."""
        self._setpoints.append(raw)
        if len(self._setpoints) > SETPOINT_INTAKE:
            self._setpoints.popleft()
            self._loop.drop_setpoints(1)

    def _hand_setpoints(self) -> None:
        """Decode the kept setpoints and queue them in arrival order; the first tick after its stamp
        activates one (hsa_core.controller.control_loop)."""
        while self._setpoints:
            try:
                msg = deserialize_message(self._setpoints.popleft(), Setpoint)
            except (
                RMWError
            ) as exc:  # malformed CDR: the typed subscription's middleware used to drop it unseen
                self._loop.refuse_setpoint(f"undecodable: {exc}")
                self.get_logger().warning(
                    f"rejected an undecodable setpoint (malformed CDR); "
                    f"{self._loop.counters.rejected_setpoints} rejected so far",
                    throttle_duration_sec=self._p["rejection_log_period"],
                )
                continue
            setpoint = CoreSetpoint(
                convert.planar_pose(msg.chiee_des),
                convert.configuration(msg.q_des),
                np.asarray(msg.phi_ss, dtype=np.float64),
                msg.optimality_error,
            )
            self._loop.receive_setpoint(convert.stamp_ns(msg.header.stamp), setpoint, msg)

    def _on_estop(self, msg: Bool) -> None:
        """E-stop state from the driver: on entry the loop resets the integrators and drops the held
        command."""
        active = bool(msg.data)
        if not self._loop.set_estop(active):
            return
        if active:
            self.get_logger().error("E-STOP: no phi_cmd is sent, integrators reset")
        else:
            self.get_logger().warning(
                "E-stop cleared: resuming from a fresh controller state (integrators zero)"
            )

    def _tick(self) -> None:
        """One control period: the loop decides; publish the new or held command and the tick's
        info, and log."""
        now = self.get_clock().now()
        self._hand_setpoints()
        if (
            self._newest is not None
            and (rates := self._tick_estimator.update(*self._newest)) is not None
        ):
            self._hand_state(
                self._newest[0], self._newest[1], rates[0], self._newest[2], rates[1], True
            )
        before = self._loop.active_tag, self._loop.counters.rejected_setpoints
        tick = self._loop.tick(now.nanoseconds)
        self._log_activations(tick, *before)
        if tick.transition is not None:
            self._log_transition(tick)
        if tick.refused is not None:
            self.get_logger().error(
                f"tick refused: {tick.refused}",
                throttle_duration_sec=self._p["rejection_log_period"],
            )
            self._publish_info(now, ControllerInfo.STATE_WAITING_FOR_STATE, commanded=False)
        elif tick.sent is Action.STEP:
            self._cmd_pub.publish(command_msg(tick.command, now))
            self._last_info = tracking_info(
                tick,
                now,
                self._kind.value,
                self._loop.active_tag,
                self._motor_map.motor_angles(tick.command.phi),
            )
            self._info_pub.publish(self._last_info)
        elif tick.sent is Action.HOLD:
            self._cmd_pub.publish(command_msg(tick.command, now))
            self._publish_info(now, ControllerInfo.STATE_HOLD_STALE, commanded=True)
        else:
            self._publish_info(now, INFO_STATE[tick.mode], commanded=False)

    def _publish_info(self, now: Time, state: int, commanded: bool) -> None:
        """Info of a tick without a step (nothing before the first tracking tick)."""
        if self._last_info is not None:
            self._info_pub.publish(
                repeated_info(
                    self._last_info,
                    now,
                    state,
                    self._loop.active_tag,
                    self._loop.controller.state,
                    commanded,
                )
            )

    def _log_activations(self, tick: Tick, active: Setpoint | None, rejected: int) -> None:
        """Log the setpoints this tick activated (DEBUG) or refused (WARN, at most once per
        rejection_log_period); active and rejected: the active setpoint and the refusals before the
        tick."""
        for activation in tick.activated:
            msg = activation.tag
            if activation.problem is None:
                active = msg
                self.get_logger().debug(
                    f"setpoint {msg.trajectory_index}/{msg.trajectory_length} active"
                )
                continue
            rejected += 1
            kept = "keeping the previous setpoint" if active is not None else "no setpoint active"
            self.get_logger().warning(
                f"rejected setpoint {msg.trajectory_index}: {activation.problem}; {kept} "
                f"({rejected} rejected so far)",
                throttle_duration_sec=self._p["rejection_log_period"],
            )

    def _log_transition(self, tick: Tick) -> None:
        """Log a mode change once (INFO back to tracking, WARN entering the hold, ERROR when
        commands stop for missing states, a lost driver or the driver's torque off)."""
        change, log = tick.transition, self.get_logger()
        text = f"{change.old.value} -> {change.new.value}"
        age, silence = tick.decision.age_s, tick.decision.driver_silence_s
        if change.new is Mode.TRACKING:
            log.info(
                text
                if np.isnan(change.outage_s)
                else f"{text} after {change.outage_s:.3f} s without tracking"
            )
        elif change.new is Mode.HOLD:
            log.warning(
                f"{text}: newest state {age:.3f} s old; re-publishing the last command, "
                "integrators frozen"
            )
        elif change.new is Mode.STALE:
            log.error(
                f"{text}: newest state {age:.3f} s old; no command is sent (the driver's watchdog "
                "holds the motors), integrators frozen"
            )
        elif change.new is Mode.DRIVER_LOST:
            log.error(
                f"{text}: no phi_present from the driver for {silence:.3f} s; no command is sent, "
                "integrators frozen until it returns"
            )
        elif change.new is Mode.TORQUE_OFF:
            log.error(
                f"{text}: the driver reports its servos' torque off; no command is sent, "
                "integrators frozen until torque is on again"
            )
        else:  # start-up, and E-stop changes (logged as ERROR/WARN when the estop message arrives)
            log.info(text)


def main() -> None:
    """Console script `controller_node`."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(ControllerNode, "controller_node"))

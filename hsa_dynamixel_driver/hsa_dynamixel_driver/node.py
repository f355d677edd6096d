"""dynamixel_driver: lifecycle node between ``phi_cmd`` and the 4 MX-28 servos (one sync write + one sync read a cycle).

Safety (planning_and_control.md §5, §7; ecosystem.md §2): goals are clipped to [0, φ_max], clamped to absolute tick
limits around the configured neutral ticks (parameter or persisted calibration, never a value read at start) and
rate-limited whatever arrives; torque goes off on deactivate, cleanup, shutdown, error, SIGINT/SIGTERM, uncaught
exceptions and the E-stop (latched until ``clear_estop``); torque is enabled only while the servos answer, report no
hardware error and their present positions are sane, and a torque-on that failed on the bus is retried with backoff;
the latched ``torque`` topic says whether phi_cmd moves the servos; a command watchdog holds or relaxes the motors;
bus errors are counted and reported, and the bus is reopened every ``reconnect_period`` while it is down. See
docs/nodes/hsa_dynamixel_driver.md.

ROS wiring only: the decisions are `hsa_core.servo_supervision.ServoSupervisor`'s, the bus I/O around them
`servos.Servos`, the goal pipeline `goals.GoalPipeline`, diagnostics `reports`, parameters `params.SPECS`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from hsa_common import convert, lockstep, qos
from hsa_common.diagnostics import Diagnostics
from hsa_common.parameters import declare, guard_updates
from hsa_common.runner import run
from hsa_core.actuation import RejectionLog, ticks_to_angles
from hsa_core.jaxsetup import configure_jax
from hsa_core.servo_supervision import Answer, Verdict, WatchdogEvent
from hsa_dynamixel_driver.bus import VELOCITY_UNIT_RAD_S, BusError, PortError
from hsa_dynamixel_driver.params import SPECS
from hsa_dynamixel_driver.reports import add_statuses
from hsa_dynamixel_driver.servos import Servos
from hsa_msgs.msg import PlanarActuation

SUCCESS = TransitionCallbackReturn.SUCCESS


class DynamixelDriver(LifecycleNode):
    """Writes the newest phi_cmd as clamped goal ticks and publishes the servos' present state, at ``rate``."""

    def __init__(self) -> None:
        """Declare the parameters, fix the configured neutral and create the graph interface."""
        super().__init__("dynamixel_driver")
        self._p: dict[str, Any] = declare(self, SPECS)
        guard_updates(self, SPECS, self._p.update)
        self._servos = Servos(self._p, self.get_logger(), self._now)
        self._sup, self._goals, self._counts = self._servos.sup, self._servos.goals, self._servos.counts
        self._rejections = RejectionLog()
        self._cycle_timer: Timer | None = None
        self._reconnect_timer: Timer | None = None
        self._state_pubs: tuple[LifecyclePublisher, ...] = ()  # motor_states, phi_present, motor_goal_stamp

        self.create_subscription(PlanarActuation, "phi_cmd", self._on_command, qos.COMMAND,
                                 qos_overriding_options=qos.overridable())
        self.create_service(SetBool, "set_torque", self._on_set_torque)
        self.create_service(Trigger, "reboot", lambda req, res: self._on_reboot(self._servos.ids, res))
        for dxl_id in self._servos.ids:
            self.create_service(Trigger, f"reboot_{dxl_id}", lambda req, res, i=dxl_id: self._on_reboot([i], res))
        # estop and torque are plain latched publishers: their state goes out in every lifecycle state (torque off
        # at deactivate, cleanup and shutdown); the servo state topics are lifecycle publishers (on_configure)
        self._pub_estop = self.create_publisher(Bool, "estop", qos.LATCHED)
        self._pub_estop.publish(Bool(data=False))
        self._pub_torque = self.create_publisher(Bool, "torque", qos.LATCHED)
        self._torque_reported: bool | None = None  # the value last published on `torque`
        self.create_service(Trigger, "estop", self._on_estop)
        self.create_service(Trigger, "clear_estop", self._on_clear_estop)
        # reliable, volatile, depth 10: matches any reliable publisher, and a quick True/False pair loses nothing
        self.create_subscription(Bool, "estop_request", self._on_estop_request, qos.INFO)
        add_statuses(Diagnostics(self, hardware_id=self._p["port"]), self._servos, self._p,
                     lambda: self.get_clock().now().nanoseconds)
        if self._p["autostart"]:  # from the executor, so torque is never on outside the runner's shutdown guard
            self._autostart_timer: Timer | None = self.create_timer(0.0, self._autostart)

    def _now(self) -> float:
        """Node-clock time [s]: every timing decision uses it, so with use_sim_time it is simulated time."""
        return self.get_clock().now().nanoseconds * 1e-9

    def lockstep_ready(self) -> bool:
        """Lockstep: simulated time may start once the bus is connected, the driver active and torque on if wanted."""
        return self._sup.active and self._sup.link_up and (self._sup.torque_on or not self._sup.torque_wanted)

    def _autostart(self) -> None:
        """One-shot: configure and activate without a lifecycle manager."""
        if self._autostart_timer is None:
            return  # an event the EventsExecutor had queued before the timer was destroyed
        self.destroy_timer(self._autostart_timer)
        self._autostart_timer = None
        try:
            if self.trigger_configure() == SUCCESS:
                self.trigger_activate()
        except _rclpy.RCLError:
            if self.context.ok():
                raise  # otherwise a signal shut the context down mid-transition: the runner's hook follows

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Create the state publishers and the bus and try to open it; while it is absent the reconnect timer keeps
        trying."""
        options = qos.overridable()
        self._state_pubs = tuple(
            self.create_lifecycle_publisher(kind, topic, qos.SENSOR, qos_overriding_options=options) for kind, topic
            in ((JointState, "motor_states"), (PlanarActuation, "phi_present"), (PlanarActuation, "motor_goal_stamp")))
        self._servos.configure()
        # the bus is hardware: reconnection runs on the steady clock, also while simulated time stands still
        self._reconnect_timer = lockstep.wall_timer(self, self._p["reconnect_period"], self._servos.reconnect)
        self._servos.connect()
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable the state publishers and torque holding the present position (if sane); start the control cycle."""
        super().on_activate(state)
        self._goals.clear()
        if self._sup.activate():
            self._servos.enable_torque()
        self._cycle_timer = self.create_timer(1.0 / self._p["rate"], self._cycle)
        self._report_torque()
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle, switch torque off and say so on `torque`; the state publishers fall silent."""
        self._stop_cycle()
        self._servos.disable_torque("deactivated")
        self._report_torque()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Torque off, close the bus and destroy the state publishers."""
        self._release("cleaned up")
        self._report_torque()
        for pub in self._state_pubs:
            self.destroy_lifecycle_publisher(pub)
        self._state_pubs = ()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState | None = None) -> TransitionCallbackReturn:
        """Torque off and close the bus: the lifecycle transition, and the runner's exit hook (signals, exceptions)."""
        self._release("shut down")
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: torque off, close the bus, go back to unconfigured."""
        self.get_logger().error("lifecycle transition failed: torque off, bus closed")
        self._release("error")
        return SUCCESS

    def _stop_cycle(self) -> None:
        """Deactivate the supervisor and stop the control timer."""
        self._sup.deactivate()
        if self._cycle_timer is not None:
            self.destroy_timer(self._cycle_timer)
            self._cycle_timer = None

    def _release(self, reason: str) -> None:
        """Torque off (best effort, no ROS needed), close the port and stop the timers; idempotent."""
        self._servos.release(reason)
        self._stop_cycle()
        if self._reconnect_timer is not None:
            self.destroy_timer(self._reconnect_timer)
            self._reconnect_timer = None

    # ------------------------------------------------------------------ commands and services
    def _on_command(self, msg: PlanarActuation) -> None:
        """Keep the newest finite command (ignored while the E-stop is engaged); the cycle writes it."""
        verdict = self._sup.command(bool(np.all(np.isfinite(msg.phi))))
        if verdict is Verdict.REJECT:
            self._counts["rejected"] += 1
            self._log_rejection("rejected", f"non-finite phi {list(msg.phi)}")
            return
        if verdict is Verdict.IGNORE:
            self._counts["ignored"] += 1
            return
        self._counts["commands"] += 1
        if verdict is Verdict.WAKE and self._servos.enable_torque() is None:
            self.get_logger().info("phi_cmd resumed: torque on again after the watchdog relaxed the motors")
        self._goals.take(msg)
        self._sup.command_taken(self._now())
        if self._p["write_on_command"] and self._sup.active and self._sup.link_up:
            try:  # the goal leaves now instead of waiting up to one read period (compute-path latency)
                self._write_goal()
            except BusError as exc:
                self._servos.count_error(exc)  # the next cycle retries the write and handles a lost link

    def _log_rejection(self, kind: str, detail: str) -> None:
        """WARN about a rejected or clipped command, throttled by RejectionLog (the counters count every one)."""
        line = self._rejections.record(kind, detail, self._now())
        if line is not None:
            self.get_logger().warning(line)

    @staticmethod
    def _answer(response: Any, answer: Answer) -> Any:
        """Fill a SetBool or Trigger response."""
        response.success, response.message = answer.success, answer.message
        return response

    def _on_set_torque(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """Torque on (if active, connected, not E-stopped and sane) or off."""
        if not request.data:
            self._sup.torque_unwanted()
            self._servos.disable_torque("set_torque service")
            return self._answer(response, Answer(True, "torque off"))
        refusal = self._sup.set_torque_refusal()
        return self._answer(response, refusal or self._sup.set_torque_result(self._servos.enable_torque()))

    def _on_reboot(self, ids: list[int], response: Trigger.Response) -> Trigger.Response:
        """Services ``reboot`` (all servos) and ``reboot_<id>``: Protocol 2.0 REBOOT to clear a latched hardware error
        (refused while tracking fresh commands with torque on; torque stays off until ``set_torque(true)``)."""
        return self._answer(response, self._servos.reboot(ids))

    def _engage_estop(self, reason: str) -> str:
        """Torque off at once, stop writing goals and ignore phi_cmd until clear_estop; returns the torque outcome."""
        unconfirmed = self._servos.disable_torque("E-stop")
        self._servos.clear_command()
        outcome = self._sup.torque_off_outcome(unconfirmed)
        if self._sup.engage_estop(reason, self._now()):
            self._counts["estops"] += 1
            self._pub_estop.publish(Bool(data=True))
            self.get_logger().error(f"E-stop engaged ({reason}): {outcome}; phi_cmd ignored until clear_estop")
        return outcome

    def _on_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Service ``estop``: engage (idempotent); success means the stop is latched, the message gives torque."""
        return self._answer(response, Answer(True, f"E-stop engaged: {self._engage_estop('estop service')}"))

    def _on_estop_request(self, msg: Bool) -> None:
        """Topic ``estop_request``: True engages the E-stop; False is ignored (only clear_estop releases it)."""
        if msg.data:
            self._engage_estop("estop_request topic")

    def _on_clear_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Service ``clear_estop``: release only if torque can be re-enabled safely (same checks as a reconnect)."""
        answer = self._sup.clear_estop_refusal()
        if answer is None:
            answer = self._sup.clear_estop_result(self._servos.enable_torque())
            if answer.success:
                self._pub_estop.publish(Bool(data=False))
                self.get_logger().warning("E-stop cleared: torque on, holding the present positions")
        return self._answer(response, answer)

    # ------------------------------------------------------------------ control cycle
    def _report_torque(self) -> None:
        """Publish on `torque` whether phi_cmd moves the servos (hsa_core ServoSupervisor.takes_commands), on change."""
        value = self._sup.takes_commands()
        if value != self._torque_reported:
            self._torque_reported = value
            self._pub_torque.publish(Bool(data=value))

    def _cycle(self) -> None:
        """One control cycle (then the torque report): see `_exchange`."""
        self._exchange()
        self._report_torque()

    def _exchange(self) -> None:
        """Watchdog, a due torque-on retry, at most one sync write of the newest command, then one sync read."""
        now = self._now()
        self._counts["cycles"] += 1
        if not self._sup.link_up:
            return
        self._check_watchdog(now)
        if self._sup.torque_retry_due(now):
            self._servos.enable_torque()
        try:
            self._write_goal()
            reading = self._servos.bus.read_positions()
            self._counts["reads"] += 1
            self._publish_state(reading.ticks, reading.velocities)
            if self._sup.alerts_changed(reading.alerts):
                self._servos.alerts(reading.alerts)
        except BusError as exc:
            self._servos.count_error(exc)
            if self._sup.cycle_failed(isinstance(exc, PortError)):
                self._servos.lose_link(exc)
            return
        self._sup.cycle_succeeded()

    def _check_watchdog(self, now: float) -> None:
        """Command watchdog: act on the supervisor's decision (log once on expiry, relax, drop a stale target)."""
        timeout = self._p["command_timeout"]
        decision = self._sup.check_watchdog(now, timeout, self._p["watchdog_action"])
        if decision.event in (WatchdogEvent.HOLD, WatchdogEvent.RELAX):
            self.get_logger().warning(f"no phi_cmd for > {timeout} s: " + (
                "relaxing (torque off)" if decision.event is WatchdogEvent.RELAX else "holding the last goal"))
        if decision.torque_off:
            self._servos.disable_torque("watchdog: no phi_cmd")
        if decision.stale:
            self._goals.drop_target()
        elif decision.event is WatchdogEvent.RESUMED:
            self.get_logger().info("phi_cmd resumed")

    def _write_goal(self) -> None:
        """Sync-write the clamped (and rate-limited) goal of the newest command, if there is something to write."""
        if not self._sup.torque_on:
            self._goals.pending = False
            return
        servos, now = self._servos, self._now()
        assert servos.map is not None and servos.limits is not None and servos.bus is not None
        step = self._goals.next_goal(now, servos.map, servos.limits, self._p["max_goal_rate"], 1.0 / self._p["rate"])
        if step is None:
            return
        if step.clipped is not None:
            self._counts["clamped"] += 1
            self._log_rejection("clipped", step.clipped)
        self._counts["rate_limited"] += step.rate_limited
        servos.bus.write_goals({i: int(t) for i, t in zip(servos.ids, step.ticks)})
        self._goals.written(step.ticks, now)
        self._counts["writes"] += 1
        # a goal cannot leave before the command it came from: under simulated time a phi_cmd may be taken before
        # this node has seen the /clock of the tick that sent it
        command = self._goals.command
        issued = convert.stamp_ns(command.header.stamp) if command is not None else 0
        self._state_pubs[2].publish(convert.actuation_msg(servos.map.present_twists(step.ticks),
                                                     convert.stamp_msg(max(self.get_clock().now().nanoseconds, issued)),
                                                     source_stamp=self._goals.target_source))

    def _publish_state(self, ticks_by_id: dict[int, int], velocities: dict[int, int]) -> None:
        """Publish motor_states and phi_present of one sync read."""
        servos = self._servos
        assert servos.map is not None
        ticks = servos.present_ticks(ticks_by_id)
        stamp = self.get_clock().now().to_msg()
        joints = JointState(name=[f"motor_{i}" for i in servos.ids],
                            position=ticks_to_angles(ticks, servos.map.neutral_ticks).tolist(),
                            velocity=[velocities[i] * VELOCITY_UNIT_RAD_S for i in servos.ids])
        joints.header.stamp = stamp
        motor_states, phi_present, _ = self._state_pubs
        motor_states.publish(joints)
        phi_present.publish(convert.actuation_msg(servos.map.present_twists(ticks), stamp))


def main() -> None:
    """Console entry point ``dynamixel_driver``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(DynamixelDriver, "dynamixel_driver"))

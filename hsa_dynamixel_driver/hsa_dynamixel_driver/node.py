"""dynamixel_driver: lifecycle node between ``phi_cmd`` and the 4 MX-28 servos (one sync write + one
sync read a cycle).

Safety (planning_and_control.md §5, §7; ecosystem.md §2): goals are clipped to [0, φ_max], clamped
to absolute tick limits around the configured neutral ticks (parameter or persisted calibration,
never a value read at start) and rate-limited whatever arrives; torque goes off on deactivate,
cleanup, shutdown, error, SIGINT/SIGTERM, uncaught exceptions and the E-stop (latched until
``clear_estop``); torque is enabled only while the servos answer, report no hardware error and their
present positions are sane, and a torque-on that failed on the bus is retried with backoff; the
latched ``torque`` topic says whether phi_cmd moves the servos; a command watchdog holds or relaxes
the motors; bus errors are counted and reported, and the bus is reopened every ``reconnect_period``
while it is down. See docs/nodes/hsa_dynamixel_driver.md.

ROS wiring only: the decisions are `hsa_core.driver.servo_supervision.ServoSupervisor`'s;
`servos.Servos` owns the state (bus, supervisor, goal pipeline `goals.GoalPipeline`, counters) and
takes one call per event; diagnostics `reports`, parameters `params.SPECS`.
"""

from __future__ import annotations

from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import (
    LifecycleNode,
    LifecyclePublisher,
    LifecycleState,
    TransitionCallbackReturn,
)
from rclpy.timer import Timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from hsa_common import convert, lockstep, qos
from hsa_common.diagnostics import Diagnostics
from hsa_common.parameters import declare, guard_updates
from hsa_common.runner import run
from hsa_core.driver.servo_supervision import Answer
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.actuation import ticks_to_angles
from hsa_dynamixel_driver.bus import VELOCITY_UNIT_RAD_S
from hsa_dynamixel_driver.params import SPECS
from hsa_dynamixel_driver.reports import add_statuses
from hsa_dynamixel_driver.servos import GoalOut, Servos
from hsa_msgs.msg import PlanarActuation

SUCCESS = TransitionCallbackReturn.SUCCESS


class DynamixelDriver(LifecycleNode):
    """Writes the newest phi_cmd as clamped goal ticks and publishes the servos' present state, at
    ``rate``."""

    # a graph stop's torque-off: the runner tears this process down without delay
    stops_first = True

    def __init__(self) -> None:
        """Declare the parameters, fix the configured neutral and create the graph interface."""
        super().__init__("dynamixel_driver")
        self._p: dict[str, Any] = declare(self, SPECS)
        guard_updates(self, SPECS, self._p.update)
        self._servos = Servos(self._p, self.get_logger(), self._now)
        self._cycle_timer: Timer | None = None
        self._reconnect_timer: Timer | None = None
        self._state_pubs: tuple[
            LifecyclePublisher, ...
        ] = ()  # motor_states, phi_present, motor_goal_stamp

        self.create_subscription(
            PlanarActuation,
            "phi_cmd",
            self._on_command,
            qos.COMMAND,
            qos_overriding_options=qos.overridable(),
        )
        self.create_service(SetBool, "set_torque", self._on_set_torque)
        self.create_service(
            Trigger, "reboot", lambda req, res: self._on_reboot(self._servos.ids, res)
        )
        for dxl_id in self._servos.ids:
            self.create_service(
                Trigger, f"reboot_{dxl_id}", lambda req, res, i=dxl_id: self._on_reboot([i], res)
            )
        # estop and torque are plain latched publishers: their state goes out in every lifecycle
        # state (torque off at deactivate, cleanup and shutdown); the servo state topics are
        # lifecycle publishers (on_configure)
        self._pub_estop = self.create_publisher(Bool, "estop", qos.LATCHED)
        self._pub_estop.publish(Bool(data=False))
        self._pub_torque = self.create_publisher(Bool, "torque", qos.LATCHED)
        self._torque_reported: bool | None = None  # the value last published on `torque`
        self.create_service(Trigger, "estop", self._on_estop)
        self.create_service(Trigger, "clear_estop", self._on_clear_estop)
        # reliable, volatile, depth 10: matches any reliable publisher, and a quick True/False pair
        # loses nothing
        self.create_subscription(Bool, "estop_request", self._on_estop_request, qos.INFO)
        add_statuses(
            Diagnostics(self, hardware_id=self._p["port"]),
            self._servos,
            self._p,
            lambda: self.get_clock().now().nanoseconds,
        )
        if self._p[
            "autostart"
        ]:  # from the executor, so torque is never on outside the runner's shutdown guard
            self._autostart_timer: Timer | None = self.create_timer(0.0, self._autostart)

    def _now(self) -> float:
        """Node-clock time [s]: every timing decision uses it, so with use_sim_time it is simulated
        time."""
        return self.get_clock().now().nanoseconds * 1e-9

    def lockstep_ready(self) -> bool:
        """Lockstep: simulated time may start once the bus is connected, the driver active and
        torque on if wanted."""
        return self._servos.lockstep_ready()

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
                # otherwise a signal shut the context down mid-transition: the runner's hook follows
                raise

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Create the state publishers and the bus and try to open it; while it is absent the
        reconnect timer keeps trying."""
        options = qos.overridable()
        self._state_pubs = tuple(
            self.create_lifecycle_publisher(kind, topic, qos.SENSOR, qos_overriding_options=options)
            for kind, topic in (
                (JointState, "motor_states"),
                (PlanarActuation, "phi_present"),
                (PlanarActuation, "motor_goal_stamp"),
            )
        )
        self._servos.configure()
        # the bus is hardware: reconnection runs on the steady clock, also while simulated time
        # stands still
        self._reconnect_timer = lockstep.wall_timer(
            self, self._p["reconnect_period"], self._servos.reconnect
        )
        self._servos.connect()
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable the state publishers and torque holding the present position (if sane); start the
        control cycle."""
        super().on_activate(state)
        self._servos.activate()
        self._cycle_timer = self.create_timer(1.0 / self._p["rate"], self._cycle)
        self._report_torque()
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle, switch torque off and say so on `torque`; the state publishers fall
        silent."""
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
        """Torque off and close the bus: the lifecycle transition, and the runner's exit hook
        (signals, exceptions)."""
        self._release("shut down")
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: torque off, close the bus, go back to unconfigured."""
        self.get_logger().error("lifecycle transition failed: torque off, bus closed")
        self._release("error")
        return SUCCESS

    def _stop_cycle(self) -> None:
        """Deactivate the supervisor and stop the control timer."""
        self._servos.deactivate()
        if self._cycle_timer is not None:
            self.destroy_timer(self._cycle_timer)
            self._cycle_timer = None

    def _release(self, reason: str) -> None:
        """Torque off (best effort, no ROS needed), close the port and stop the timers;
        idempotent."""
        self._servos.release(reason)
        self._stop_cycle()
        if self._reconnect_timer is not None:
            self.destroy_timer(self._reconnect_timer)
            self._reconnect_timer = None

    # ------------------------------------------------------------------ commands and services
    def _on_command(self, msg: PlanarActuation) -> None:
        """Hand the command to the servos; publish the goal stamp if its goal left at once."""
        self._publish_goal(self._servos.take_command(msg))

    @staticmethod
    def _answer(response: Any, answer: Answer) -> Any:
        """Fill a SetBool or Trigger response."""
        response.success, response.message = answer.success, answer.message
        return response

    def _on_set_torque(
        self, request: SetBool.Request, response: SetBool.Response
    ) -> SetBool.Response:
        """Torque on (if active, connected, not E-stopped and sane) or off."""
        return self._answer(response, self._servos.set_torque(request.data))

    def _on_reboot(self, ids: list[int], response: Trigger.Response) -> Trigger.Response:
        """Services ``reboot`` (all servos) and ``reboot_<id>``: Protocol 2.0 REBOOT to clear a
        latched hardware error (refused while tracking fresh commands with torque on; torque stays
        off until ``set_torque(true)``)."""
        return self._answer(response, self._servos.reboot(ids))

    def _engage_estop(self, reason: str) -> str:
        """Engage the E-stop (publish it when newly engaged); returns the torque-off outcome."""
        engaged, outcome = self._servos.engage_estop(reason)
        if engaged:
            self._pub_estop.publish(Bool(data=True))
        return outcome

    def _on_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Service ``estop``: engage (idempotent); success means the stop is latched, the message
        gives torque."""
        return self._answer(
            response, Answer(True, f"E-stop engaged: {self._engage_estop('estop service')}")
        )

    def _on_estop_request(self, msg: Bool) -> None:
        """Topic ``estop_request``: True engages the E-stop; False is ignored (only clear_estop
        releases it)."""
        if msg.data:
            self._engage_estop("estop_request topic")

    def _on_clear_estop(
        self, request: Trigger.Request, response: Trigger.Response
    ) -> Trigger.Response:
        """Service ``clear_estop``: release only if torque can be re-enabled safely (same checks as
        a reconnect)."""
        answer, released = self._servos.clear_estop()
        if released:
            self._pub_estop.publish(Bool(data=False))
        return self._answer(response, answer)

    # ------------------------------------------------------------------ control cycle
    def _report_torque(self) -> None:
        """Publish on `torque` whether phi_cmd moves the servos (hsa_core
        ServoSupervisor.takes_commands), on change."""
        value = self._servos.sup.takes_commands()
        if value != self._torque_reported:
            self._torque_reported = value
            self._pub_torque.publish(Bool(data=value))

    def _cycle(self) -> None:
        """One control cycle (`Servos.exchange`): publish what it wrote and read, then `torque`."""
        exchange = self._servos.exchange()
        self._publish_goal(exchange.goal)
        if exchange.reading is not None:
            self._publish_state(exchange.reading.ticks, exchange.reading.velocities)
        self._report_torque()

    def _publish_goal(self, goal: GoalOut | None) -> None:
        """Publish motor_goal_stamp of a written goal: never stamped before the command it came from
        (under simulated time a phi_cmd may be taken before this node has seen the /clock of the
        tick that sent it)."""
        if goal is None:
            return
        issued = convert.stamp_ns(goal.issued) if goal.issued is not None else 0
        stamp = convert.stamp_msg(max(self.get_clock().now().nanoseconds, issued))
        msg = convert.actuation_msg(goal.phi, stamp, source_stamp=goal.source_stamp)
        self._state_pubs[2].publish(msg)

    def _publish_state(self, ticks_by_id: dict[int, int], velocities: dict[int, int]) -> None:
        """Publish motor_states and phi_present of one sync read."""
        servos = self._servos
        assert servos.map is not None
        ticks = servos.present_ticks(ticks_by_id)
        stamp = self.get_clock().now().to_msg()
        joints = JointState(
            name=[f"motor_{i}" for i in servos.ids],
            position=ticks_to_angles(ticks, servos.map.neutral_ticks).tolist(),
            velocity=[velocities[i] * VELOCITY_UNIT_RAD_S for i in servos.ids],
        )
        joints.header.stamp = stamp
        motor_states, phi_present, _ = self._state_pubs
        motor_states.publish(joints)
        phi_present.publish(convert.actuation_msg(servos.map.present_twists(ticks), stamp))


def main() -> None:
    """Console entry point ``dynamixel_driver``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(DynamixelDriver, "dynamixel_driver"))

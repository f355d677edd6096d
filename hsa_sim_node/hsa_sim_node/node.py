"""sim_node: replaces the hardware — an emulated MX-28 bus for the driver and mocap poses of the
simulated world.

The world (plant, servos, motion capture) is :class:`hsa_core.sim.world.World`, the same as the
offline experiment's. The emulated servos' shafts are the world's: goals the driver writes reach the
world (with their write time), Present Position reads report the world's shafts. Two clocks
(docs/simulation.md):

* ``lockstep`` (parameter ``lockstep: true``): the node owns /clock. Simulated time starts when
  every expected participant is ready, and moves from instant to instant only when the barrier
  (:mod:`hsa_core.sim.lockstep`) says the graph has finished with the current one (decisions:
  :mod:`hsa_core.sim.sim_lockstep`); mocap samples are published at the instants they become
  available. A barrier that does not finish within ``barrier_timeout`` seconds of wall time is an
  ERROR, and the node exits 1.
* ``wall``: the world follows the node clock; a timer at the mocap rate publishes every sample that
  became available.
A ``payload`` is the plant's from t = 0 (it hangs at rest with it); a ``payload_schedule`` changes
the plant's payload at given instants of simulated time (:meth:`World.set_payload`). See
docs/nodes/hsa_sim_node.md.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from rosgraph_msgs.msg import Clock

from hsa_common import convert, lockstep, qos
from hsa_common.diagnostics import Diagnostics, Report
from hsa_common.model_params import (
    MODEL_SPECS,
    WIRING_SPEC,
    check_sigma_a_eq,
    load_model,
    load_wiring_param,
)
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare
from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_core.rate_meter import RateMeter
from hsa_core.sensing.mocap import planar_to_world
from hsa_core.sim.disturbance import WORLDS, named_world
from hsa_core.sim.lockstep import Barrier
from hsa_core.sim.playback import Action, Step
from hsa_core.sim.run_conditions import plant_params, rest_strain_shift, run_disturbance
from hsa_core.sim.sim_lockstep import SimLockstep
from hsa_core.sim.world import MOCAP_PERIOD_NS, MocapSample, World, payload_schedule
from hsa_msgs.msg import LockstepAck, LockstepLead
from hsa_sim_node.mx28_emulator import (
    ADDR_GOAL_POSITION,
    ADDR_TORQUE_ENABLE,
    BAUD_RATE_CODES,
    MX28Emulator,
)
from hsa_sim_node.reports import emulator_report, torque_at_exit, world_report

# s the emulated bus outlives a stop signal (the driver's torque-off lands first)
SHUTDOWN_GRACE = 0.5
# s of wall time after which an unanswered /clock is sent again (/clock is best effort)
CLOCK_RESEND = 0.05
GIL_SWITCH_INTERVAL = 5e-4
"""[s] Python thread switch interval of this process (default 5 ms): the emulator's serving thread
must answer within the Dynamixel SDK's wall-clock packet timeout (≈ 34 ms) while the main thread
handles the barrier's reports; with the default, reads timed out on a busy machine
(docs/simulation.md)."""
# lockstep: give the executor a turn at least this often (acks, services)
MAX_INSTANTS_PER_PUMP = 1000


def _initial_ticks(value: list[int] | None) -> str | None:
    """Refusal of power-on positions that are not unset/empty (the wiring's nominal) or 4 ticks
    within ±1e6."""
    if value is None or len(value) == 0:
        return None
    if len(value) != 4 or not all(abs(v) <= 1_000_000 for v in value):
        return f"must be empty or 4 tick counts within ±1e6, got {list(value)!r}"
    return None


def _payload_problem(value: list[float] | None) -> str | None:
    """Refusal of a malformed payload schedule (unset or empty: no payload)."""
    try:
        payload_schedule(value or [])
    except ValueError as exc:
        return str(exc)
    return None


SPECS = (
    ParamSpec(
        "port",
        "",
        "symlink the emulated bus appears at; empty = /tmp/hsa_ros_<ROS_DOMAIN_ID>/ttyDXL",
        read_only=True,
    ),
    ParamSpec(
        "baudrate",
        4_000_000,
        "Baud Rate of the emulated servos [bit/s]; the driver must use the same",
        read_only=True,
        validator=lambda v: (
            None if v in BAUD_RATE_CODES else f"must be one of {sorted(BAUD_RATE_CODES)}"
        ),
    ),
    WIRING_SPEC,
    ParamSpec(
        "initial_ticks",
        Parameter.Type.INTEGER_ARRAY,
        "power-on present positions [ticks] = the neutral "
        "(φ = 0); unset = the wiring file's nominal neutral_ticks",
        read_only=True,
        validator=_initial_ticks,
    ),
    *MODEL_SPECS,
    ParamSpec(
        "base_position",
        [0.0, 0.0, 0.0],
        "world position of the base rigid body [m]",
        length=3,
        read_only=True,
    ),
    ParamSpec(
        "platform_topic",
        "/mocap/platform/pose",
        "PoseStamped topic of the platform body",
        read_only=True,
    ),
    ParamSpec(
        "base_topic",
        "/mocap/base/pose",
        "PoseStamped topic of the base body (empty = not published)",
        read_only=True,
    ),
    ParamSpec("frame_id", "world", "frame of the published poses", read_only=True),
    ParamSpec(
        "disturbance",
        "none",
        "none: plant = model, exact poses; calibrated: the material's world fitted to the real"
        " runs (the launch files' default); declared: hsa_core DisturbanceModel(); shear: the"
        " declared world with half the shear stiffness (hsa_core.sim.disturbance.named_world)",
        choices=WORLDS,
        read_only=True,
    ),
    ParamSpec(
        "seed",
        0,
        "seed of the pose noise (every world but none)",
        low=0,
        high=2**31 - 1,
        read_only=True,
    ),
    ParamSpec(
        "participants",
        [""],
        "lockstep: fully qualified names of the nodes simulated time waits for before "
        "it starts (others join when they first report)",
        read_only=True,
    ),
    ParamSpec(
        "barrier_timeout",
        30.0,
        "lockstep: [s] of wall time an instant may take before the run fails",
        low=0.1,
        high=3600.0,
        read_only=True,
    ),
    ParamSpec(
        "payload",
        0.0,
        "[kg] the plant's point payload from t = 0, at rest with it, at the paper's payload CoG "
        "(a run's condition; hsa_core.sim.run_conditions.plant_params)",
        low=0.0,
        high=10.0,
        read_only=True,
    ),
    ParamSpec(
        "command_latency",
        0.0,
        "[s] a run's controller-side delay from a tick to its goal "
        "on the bus, added to the world's actuation latency "
        "(hsa_core.sim.run_conditions.run_disturbance)",
        low=0.0,
        high=1.0,
        read_only=True,
    ),
    ParamSpec(
        "command_queue_depth",
        0,
        "a run's command path: goals through the September driver's queue of this depth, "
        "one transaction at a time (0 = written at once; hsa_core.sim.command_queue)",
        low=0,
        high=100,
        read_only=True,
    ),
    ParamSpec(
        "command_transaction",
        0.0,
        "[s] the command queue's transaction time, a whole number of ms (with "
        "command_queue_depth > 0)",
        low=0.0,
        high=1.0,
        read_only=True,
    ),
    ParamSpec(
        "plant_sigma_a_eq",
        Parameter.Type.DOUBLE_ARRAY,
        "[-] the plant's axial rest strains of rods 1 and 2 where a run's plant and controller "
        "differ (unset or empty = sigma_a_eq; hsa_core.sim.run_conditions.run_disturbance)",
        read_only=True,
        validator=check_sigma_a_eq,
    ),
    ParamSpec(
        "payload_schedule",
        Parameter.Type.DOUBLE_ARRAY,
        "[s, kg] flat pairs [t0, m0, t1, m1, ...]: from "
        "simulated time t_k the payload (at the params' CoG_pl) is m_k; unset or empty = none",
        read_only=True,
        validator=_payload_problem,
    ),
)


class SimNode(Node):
    """Emulated servos plus the simulated world seen through the motion-capture system."""

    # the runner must not make this node a participant of its own barrier
    lockstep_coordinator = True
    # the emulated bus executes a graph stop's torque-off: no teardown delay
    stops_first = True

    def __init__(self) -> None:
        super().__init__("sim_node")
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)  # the process's: composed with other nodes too
        self._p: dict[str, Any] = declare(self, SPECS)
        wiring = load_wiring_param(self._p["wiring_file"])  # the driver's: IDs, rods, rod signs
        ids, ticks = list(wiring.motor_ids), list(self._p["initial_ticks"] or wiring.neutral_ticks)
        model = load_model(self._p)
        declared = named_world(self._p["disturbance"], self._p["material"], self._p["seed"])
        shift = rest_strain_shift(model, self._p["plant_sigma_a_eq"] or None)
        try:
            disturbance = run_disturbance(
                declared,
                self._p["command_latency"],
                shift,
                (self._p["command_queue_depth"], self._p["command_transaction"]),
            )
        except ValueError as exc:  # the queue's depth and transaction together
            raise ParameterValidationError(
                f"parameters 'command_queue_depth', 'command_transaction': {exc}"
            ) from exc
        self._map = wiring.motor_map(model, neutral_ticks=tuple(ticks))
        self._base = np.asarray(self._p["base_position"], dtype=np.float64)
        port = self._p["port"] or f"/tmp/hsa_ros_{os.environ.get('ROS_DOMAIN_ID', '0')}/ttyDXL"
        os.makedirs(os.path.dirname(port), exist_ok=True)
        plant = plant_params(model, self._p["payload"])
        # compiles: the bus appears only when it can answer in time
        self._world = World(plant, disturbance, self._map)
        self._world.set_torque([False] * len(ids))
        for t_ns, mass in payload_schedule(self._p["payload_schedule"] or []):
            self._world.set_payload(mass, t_ns)
        self._world.advance_to(0)
        self._emulator = MX28Emulator(
            ids,
            baudrate=self._p["baudrate"],
            initial_ticks=dict(zip(ids, ticks)),
            model=None,
            link_path=port,
        )
        self._sync_shafts()
        self._emulator.start()
        self.get_logger().info(f"emulated MX-28 bus of IDs {ids} at {port}")

        options = qos.overridable()
        self._pub_platform = self.create_publisher(
            PoseStamped, self._p["platform_topic"], qos.SENSOR, qos_overriding_options=options
        )
        self._pub_base = (
            self.create_publisher(
                PoseStamped, self._p["base_topic"], qos.SENSOR, qos_overriding_options=options
            )
            if self._p["base_topic"]
            else None
        )
        self._stats = {"samples": 0, "instants": 0, "resends": 0, "sim_time_ns": 0}
        self._traffic = {
            "acks": 0,
            "clocks": 0,
            "leads": 0,
            "runs": 0,
            "publishes": 0,
            "pumps": 0,  # lockstep: barrier
        }
        self._acks_by: Counter[str] = Counter()
        self._ran: list[MocapSample] = []  # lockstep: samples run to, not yet published
        self._world_rates, self._emulator_rates = (
            RateMeter(time.monotonic_ns()),
            RateMeter(time.monotonic_ns()),
        )
        self._lockstep = lockstep.enabled(self)
        self._failure = ""
        diagnostics = Diagnostics(self, hardware_id=port)
        diagnostics.add("world", self._world_report)
        diagnostics.add("emulator", self._emulator_report)
        if self._lockstep:
            self._own = lockstep.Participant(self, publish_acks=False)
            self._barrier = Barrier(n for n in self._p["participants"] if n)
            self._barrier.own = self._own.published  # live: the samples it publishes count at once
            self._coordinator = SimLockstep(
                self._barrier, self._p["barrier_timeout"], resend=CLOCK_RESEND
            )
            self._clock_pub = self.create_publisher(
                Clock, "/clock", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
            )
            self._lead_pub = self.create_publisher(
                LockstepLead, lockstep.LEAD_TOPIC, lockstep.LEAD_QOS
            )
            self.create_subscription(
                LockstepAck, lockstep.ACK_TOPIC, self._on_ack, lockstep.ACK_READER_QOS
            )
            lockstep.wall_timer(self, 0.01, self._pump)
            self.get_logger().info(f"lockstep: waiting for {list(self._barrier.expected)}")
        else:
            self._origin: Time | None = None  # node clock at world time 0
            self.create_timer(MOCAP_PERIOD_NS * 1e-9, self._follow_clock)

    # ---------------------------------------------------------------- the world behind the bus
    def _sync_shafts(self) -> None:
        """Present Position (and velocity) of the emulated servos := the world's shafts."""
        for dxl_id, ticks, velocity in zip(
            self._map.ids, self._world.position, self._world.velocity
        ):
            self._emulator.set_present_ticks(dxl_id, ticks, velocity)

    def _collect_bus(self, at_ns: int) -> None:
        """Goal writes since the last call (in order) and the torque state reach the world as of
        ``at_ns``."""
        goal = np.asarray(self._world.goal, dtype=np.float64).copy()
        writes = self._emulator.drain_writes(ADDR_GOAL_POSITION)
        index = {dxl_id: m for m, dxl_id in enumerate(self._map.ids)}
        for write in writes:
            if write.dxl_id in index:
                goal[index[write.dxl_id]] = write.value
        if writes:
            self._world.write_goals(goal, at_ns)
        self._world.set_torque([self._emulator.torque_enabled(i) for i in self._map.ids])

    def _publish_samples(self, samples: Sequence[MocapSample], origin_ns: int = 0) -> None:
        """Publish ``samples`` (stamps: world time + ``origin_ns``)."""
        for sample in samples:
            stamp, frame_id = convert.stamp_msg(sample.stamp_ns + origin_ns), self._p["frame_id"]
            position, quaternion = planar_to_world(sample.chiee, self._base)
            self._pub_platform.publish(convert.pose_stamped(stamp, frame_id, position, quaternion))
            if self._pub_base is not None:  # the base body is created aligned with the world
                self._pub_base.publish(
                    convert.pose_stamped(stamp, frame_id, self._base, (0.0, 0.0, 0.0, 1.0))
                )
            self._stats["samples"] += 1
        self._stats["sim_time_ns"] = self._world.t_ns

    # ---------------------------------------------------------------- wall clock
    def _follow_clock(self) -> None:
        """Wall clock: run the world up to the node clock and publish the samples that became
        available."""
        now = self.get_clock().now()
        if self._origin is None:
            self._origin = now
        t_ns = (now - self._origin).nanoseconds
        self._collect_bus(self._world.t_ns)
        self._world.advance_to(t_ns - t_ns % 1_000_000)
        self._sync_shafts()
        self._publish_samples(self._world.take_samples(self._world.t_ns), self._origin.nanoseconds)

    # ---------------------------------------------------------------- lockstep
    def _on_ack(self, msg: LockstepAck) -> None:
        """A participant's report: maybe the instant is finished."""
        self._traffic["acks"] += 1
        self._acks_by[msg.node] += 1
        self._barrier.report(lockstep.from_msg(msg))
        self._pump()

    def _pump(self) -> None:
        """Move simulated time as far as the barrier allows (decisions:
        :class:`hsa_core.sim.sim_lockstep.SimLockstep`)."""
        if self._failure:
            return
        self._traffic["pumps"] += 1
        for _ in range(MAX_INSTANTS_PER_PUMP):
            step = self._coordinator.step(
                time.monotonic(),
                self._world.t_ns,
                self._world.next_sample_ns(),
                self._emulator.idle,
                lambda: lockstep.matched_of(self),
            )
            if step.action is Action.CLOCK:
                self._send_clock(step.t_ns)
                if step.reason:  # resent while the barrier waits
                    self._stats["resends"] += 1
                    return self._waiting(step)
            elif step.action is Action.LEAD:
                self._traffic["leads"] += 1
                lockstep.publish_leads(self._lead_pub, step.t_ns, self._barrier.leads())
            elif step.action is Action.START:
                self.get_logger().info(
                    f"lockstep: simulated time starts ({len(self._barrier.reports)} participants)"
                )
            elif step.action is Action.FINISH:
                self._collect_bus(step.t_ns)
                self._stats["instants"] += 1
                self._publish_samples(self._world.take_samples(step.t_ns))
            elif step.action in (Action.RUN, Action.INSTANT):
                self._world.advance_to(step.t_ns)
                self._sync_shafts()
                if step.action is Action.RUN:
                    self._traffic["runs"] += 1
                    self._ran += self._world.take_samples(step.t_ns)
            elif step.action is Action.PUBLISH:
                self._traffic["publishes"] += 1
                self._publish_samples(self._ran)  # no /clock: callbacks keep the last instant's
                self._ran = []
            else:
                return self._waiting(step)

    def _waiting(self, step: Step) -> None:
        """Log why simulated time does not move (not started, stopped), or fail loudly (``fail``:
        exit code 1)."""
        if step.action is Action.STOP:
            self.get_logger().info(
                f"lockstep: {step.reason}; simulated time stops at {step.t_ns * 1e-9:.3f} s"
            )
        elif step.action is Action.FAIL:
            self._failure = step.reason
            self.get_logger().error(self._failure)
            self.exit_code = 1
            self.context.try_shutdown()
        elif not self._barrier.started:
            self.get_logger().info(
                f"lockstep: simulated time has not started: {step.reason}",
                throttle_duration_sec=5.0,
            )

    def _send_clock(self, t_ns: int) -> None:
        """Publish /clock at instant ``t_ns``."""
        self._traffic["clocks"] += 1
        self._clock_pub.publish(convert.clock_msg(t_ns))

    # ---------------------------------------------------------------- diagnostics
    def _world_report(self) -> Report:
        """``sim_node: world`` (real-time factor over the period since the previous report)."""
        rtf = (
            self._world_rates.rates(time.monotonic_ns(), {"sim_ns": self._stats["sim_time_ns"]})[
                "sim_ns"
            ]
            * 1e-9
        )
        return world_report(
            self._world, self._stats, rtf, self._lockstep, self._p["disturbance"], self._failure
        )

    def _emulator_report(self) -> Report:
        """``sim_node: emulator`` (rates over the period since the previous report)."""
        stats = self._emulator.stats()
        rates = self._emulator_rates.rates(
            time.monotonic_ns(), {"sync_writes": stats.sync_writes, "sync_reads": stats.sync_reads}
        )
        return emulator_report(self._emulator, self._map.ids, stats, rates)

    def on_shutdown(self) -> None:
        """Runner exit hook: keep the servos powered for a moment, so a driver stopping with us can
        turn torque off, then report whether it did and remove the bus."""
        if self._lockstep:  # what the barrier cost (benchmarks/bench_lockstep_breakdown.py)
            traffic = {
                "sim_time_ns": self._world.t_ns,
                "instants": self._stats["instants"],
                **self._traffic,
                "acks_by": dict(self._acks_by),
            }
            self.get_logger().info(f"lockstep: barrier traffic {json.dumps(traffic)}")
        time.sleep(SHUTDOWN_GRACE)
        on = [i for i in self._map.ids if self._emulator.torque_enabled(i)]
        self.get_logger().info(
            torque_at_exit(self._map.ids, on, self._emulator.writes(ADDR_TORQUE_ENABLE))
        )
        self._emulator.stop()


def main() -> None:
    """Console entry point ``sim_node``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(SimNode, "sim_node"))

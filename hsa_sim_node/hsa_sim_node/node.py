"""sim_node: replaces the hardware — an emulated MX-28 bus for the driver and mocap poses from the JAX plant.

Mocap samples lie on a regular grid of stamps (period 1/rate of the node clock), as a camera system's do. For every
sample due by now a timer callback publishes the platform pose (world frame) of the plant state at that stamp, then
reads the emulated servos' present ticks, converts them to φ and advances the plant by one period with φ held — the
integration happens after the publication, off the latency path. A callback
that comes late catches up (up to MAX_CATCH_UP samples); a longer stall skips samples, counted in diagnostics.
See docs/nodes/hsa_sim_node.md.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from geometry_msgs.msg import PoseStamped
from jax import Array
from rclpy.node import Node
from rclpy.time import Time

from hsa_common import qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParamSpec, declare
from hsa_common.runner import run
from hsa_core.actuation import MotorMap
from hsa_core.disturbance import DisturbanceModel
from hsa_core.kinematics import end_effector_pose
from hsa_core.mocap import planar_to_world
from hsa_core.params import HsaParams
from hsa_core.simulation import simulate, steady_state_rollout
from hsa_sim_node.mx28_emulator import ADDR_TORQUE_ENABLE, BAUD_RATE_CODES, MX28Emulator

SHUTDOWN_GRACE = 0.5  # s the emulated bus outlives a stop signal (the driver's torque-off lands first)
MAX_CATCH_UP = 4  # most mocap samples produced in one timer callback; a longer stall skips samples (counted)


def _signs(value: list[int]) -> str | None:
    return None if all(v in (-1, 1) for v in value) else "entries must be +1 or -1"


def _strains(value: list[float] | None) -> str | None:
    if not value:
        return None
    return None if len(value) == 2 and all(math.isfinite(v) and v > 0.0 for v in value) else \
        "must be unset, empty or 2 finite strains > 0"


SPECS = (
    ParamSpec("port", "", "symlink the emulated bus appears at; empty = /tmp/hsa_ros_<ROS_DOMAIN_ID>/ttyDXL",
              read_only=True),
    ParamSpec("baudrate", 4_000_000, "Baud Rate of the emulated servos [bit/s]; the driver must use the same",
              read_only=True,
              validator=lambda v: None if v in BAUD_RATE_CODES else f"must be one of {sorted(BAUD_RATE_CODES)}"),
    ParamSpec("motor_ids", [21, 22, 23, 24], "IDs of the emulated servos (order as in the driver)", low=0, high=252,
              length=4, read_only=True,
              validator=lambda v: None if len(set(v)) == len(v) else "IDs must be distinct"),
    ParamSpec("initial_ticks", [2048, 2048, 2048, 2048], "power-on present positions [ticks] = the neutral (φ = 0)",
              low=-1_000_000, high=1_000_000, length=4, read_only=True),
    ParamSpec("rho", [1, -1, 1, -1], "rod handedness of each motor [+1|-1]", length=4, read_only=True,
              validator=_signs),
    ParamSpec("h", [1, 1], "control handedness of the two virtual rods [+1|-1]", length=2, read_only=True,
              validator=_signs),
    *MODEL_SPECS,
    ParamSpec("rate", 200.0, "mocap rate: plant ticks and published poses [Hz]", low=10.0, high=1000.0,
              read_only=True),
    ParamSpec("substeps", 4, "RK4 steps per mocap period", low=1, high=100,
              read_only=True),
    ParamSpec("base_position", [0.0, 0.0, 0.0], "world position of the base rigid body [m]", length=3,
              read_only=True),
    ParamSpec("platform_topic", "/mocap/platform/pose", "PoseStamped topic of the platform body", read_only=True),
    ParamSpec("base_topic", "/mocap/base/pose", "PoseStamped topic of the base body (empty = not published)",
              read_only=True),
    ParamSpec("frame_id", "world", "frame of the published poses", read_only=True),
    ParamSpec("disturbance", "none", "none: plant = model, exact poses; default: hsa_core DisturbanceModel()",
              choices=("none", "default"), read_only=True),
    ParamSpec("seed", 0, "seed of the pose noise (disturbance 'default')", low=0, high=2**31 - 1, read_only=True),
)


def plant_step(params: HsaParams, substeps: int) -> Callable[[Array, Array, float], tuple[Array, Array]]:
    """Jitted (x, φ, dt) → (state after ``substeps`` RK4 steps of dt with φ held, its end-effector pose)."""

    @jax.jit
    def step(x: Array, phi: Array, dt: float) -> tuple[Array, Array]:
        x_next = simulate(params, x, phi[None], dt, substeps)[-1]
        return x_next, end_effector_pose(params, x_next[:3])

    return step


class SimNode(Node):
    """Emulated servos plus the simulated robot seen through the motion-capture system."""

    def __init__(self) -> None:
        super().__init__("sim_node")
        self._p: dict[str, Any] = declare(self, SPECS)
        self._period = 1.0 / self._p["rate"]
        ids, ticks = self._p["motor_ids"], self._p["initial_ticks"]
        model = load_model(self._p)
        self._disturbance = DisturbanceModel(seed=self._p["seed"]) if self._p["disturbance"] == "default" \
            else DisturbanceModel.none()
        plant = self._disturbance.plant_params(model)
        self._rng = self._disturbance.rng()
        self._map = MotorMap(tuple(ticks), tuple(ids), rho=tuple(self._p["rho"]), h=tuple(self._p["h"]))
        self._base = np.asarray(self._p["base_position"], dtype=np.float64)
        port = self._p["port"] or f"/tmp/hsa_ros_{os.environ.get('ROS_DOMAIN_ID', '0')}/ttyDXL"
        os.makedirs(os.path.dirname(port), exist_ok=True)
        self._emulator = MX28Emulator(ids, baudrate=self._p["baudrate"], initial_ticks=dict(zip(ids, ticks)),
                                      link_path=port).start()
        self.get_logger().info(f"emulated MX-28 bus of IDs {ids} at {port}; compiling the plant")

        self._step = plant_step(plant, self._p["substeps"])
        self._x = steady_state_rollout(plant, jnp.zeros(2))
        _, chiee = self._step(self._x, jnp.zeros(2), self._period / self._p["substeps"])
        self._chiee = np.asarray(chiee)
        self._phi = np.zeros(2)

        options = qos.overridable()
        self._pub_platform = self.create_publisher(PoseStamped, self._p["platform_topic"], qos.SENSOR,
                                                   qos_overriding_options=options)
        self._pub_base = (self.create_publisher(PoseStamped, self._p["base_topic"], qos.SENSOR,
                                                qos_overriding_options=options) if self._p["base_topic"] else None)
        self._stats = {"ticks": 0, "sim_time": 0.0, "overruns": 0, "skipped": 0, "compute_max": 0.0,
                       "compute_sum": 0.0}
        self._report_base = (time.monotonic(), dict(self._stats))
        self._emulator_base = (time.monotonic(), self._emulator.stats())
        self._diverged = False
        self._period_ns = round(self._period * 1e9)
        self._next_ns: int | None = None  # stamp of the next mocap sample [ns, node clock]
        self._timer = self.create_timer(self._period, self._tick)
        diagnostics = Diagnostics(self, hardware_id=port)
        diagnostics.add("plant", self._plant_report)
        diagnostics.add("emulator", self._emulator_report)

    def _tick(self) -> None:
        """Produce every mocap sample due by now, on a regular grid of stamps like a camera system's."""
        started = time.perf_counter()
        now = self.get_clock().now().nanoseconds
        if self._next_ns is None:  # the grid starts at this call's scheduled time: stamps age by the timer jitter only
            self._next_ns = now - max(self._period_ns - (self._timer.time_until_next_call() or 0), 0)
        due = (now - self._next_ns) // self._period_ns + 1
        if due <= 0:
            return
        if due > MAX_CATCH_UP:  # stalled for longer than the catch-up budget: skip, as a dropped mocap frame would
            skipped = due - MAX_CATCH_UP
            self._stats["skipped"] += skipped
            self._next_ns += skipped * self._period_ns
            due = MAX_CATCH_UP
        self._stats["overruns"] += due > 1
        for k in range(due):
            self._publish(Time(nanoseconds=self._next_ns))  # the plant state at this stamp, computed beforehand
            self._next_ns += self._period_ns
            self._stats["ticks"] += 1
            if k == 0:  # the present twists now drive the plant over the next period (zero-order hold)
                self._phi = self._map.present_twists([self._emulator.present_ticks()[i] for i in self._map.ids])
            self._advance()
        compute = time.perf_counter() - started
        self._stats["compute_sum"] += compute
        self._stats["compute_max"] = max(self._stats["compute_max"], compute)

    def _advance(self) -> None:
        """Advance the plant by one mocap period with φ held; a non-finite result freezes it at the last finite pose."""
        if self._diverged:
            return
        x, chiee = self._step(self._x, self._phi, self._period / self._p["substeps"])
        chiee = np.asarray(chiee)
        if np.all(np.isfinite(chiee)):
            self._x, self._chiee = x, chiee
            self._stats["sim_time"] += self._period
        else:
            self._diverged = True
            self.get_logger().error(f"plant diverged at φ = {self._phi.tolist()}; holding the last finite pose")

    def _publish(self, now: Time) -> None:
        """Platform (and base) body poses as a mocap system would report them."""
        measured = self._disturbance.measure(self._rng, self._chiee)
        position, quaternion = planar_to_world(measured, self._base)
        msg = PoseStamped()
        msg.header.stamp = now.to_msg()
        msg.header.frame_id = self._p["frame_id"]
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = position.tolist()
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = quaternion.tolist()
        self._pub_platform.publish(msg)
        if self._pub_base is not None:
            base = PoseStamped()
            base.header = msg.header
            base.pose.position.x, base.pose.position.y, base.pose.position.z = self._base.tolist()
            base.pose.orientation.w = 1.0  # the base body is created aligned with the world
            self._pub_base.publish(base)

    def _plant_report(self) -> Report:
        now = time.monotonic()
        since, base = self._report_base
        self._report_base = (now, dict(self._stats))
        self._stats["compute_max"] = 0.0
        ticks = self._stats["ticks"] - base["ticks"]
        wall = max(now - since, 1e-9)
        rtf = (self._stats["sim_time"] - base["sim_time"]) / wall
        values = {"rate_hz": round(ticks / wall, 1), "real_time_factor": round(rtf, 3),
                  "late_callbacks": self._stats["overruns"], "skipped_samples": self._stats["skipped"],
                  "compute_mean_ms": round(1e3 * (self._stats["compute_sum"] - base["compute_sum"]) / max(ticks, 1), 3),
                  "compute_max_ms": round(1e3 * base["compute_max"], 3), "phi": np.round(self._phi, 4).tolist(),
                  "chiee": np.round(self._chiee, 5).tolist(), "disturbance": self._p["disturbance"]}
        if self._diverged:
            return Report(ERROR, "plant diverged", values)
        if rtf < 0.95:
            return Report(WARN, f"slower than real time (factor {rtf:.2f})", values)
        return Report(OK, "running in real time", values)

    def _emulator_report(self) -> Report:
        stats = self._emulator.stats()
        now = time.monotonic()
        since, base = self._emulator_base
        self._emulator_base = (now, stats)
        elapsed = max(now - since, 1e-9)
        silent, hw_errors = self._emulator.unresponsive(), self._emulator.hardware_errors()
        values = {"port": self._emulator.port, "device": self._emulator.device, **vars(stats),
                  "sync_writes_per_s": round((stats.sync_writes - base.sync_writes) / elapsed, 1),
                  "sync_reads_per_s": round((stats.sync_reads - base.sync_reads) / elapsed, 1),
                  "unresponsive_ids": list(silent),
                  **{f"torque_{i}": self._emulator.torque_enabled(i) for i in self._map.ids},
                  **{f"hardware_error_{i}": bits for i, bits in hw_errors.items()}}
        if not self._emulator.plugged:
            return Report(ERROR, "unplugged", values)
        if silent or any(hw_errors.values()):
            return Report(WARN, f"faults: unresponsive {list(silent)}, hardware errors "
                                f"{ {i: b for i, b in hw_errors.items() if b} }", values)
        return Report(OK if stats.crc_errors == 0 else WARN, "serving", values)

    def on_shutdown(self) -> None:
        """Runner exit hook: keep the servos powered for a moment, so a driver stopping with us can turn torque off,
        then report whether it did and remove the bus."""
        time.sleep(SHUTDOWN_GRACE)
        self.get_logger().info(self._torque_at_exit())
        self._emulator.stop()

    def _torque_at_exit(self) -> str:
        """Which servos still have torque on; else since when every servo is off (CLOCK_MONOTONIC of the first
        torque-off write after each servo's last torque-on write, latest over the servos)."""
        on = [i for i in self._map.ids if self._emulator.torque_enabled(i)]
        if on:
            return f"emulated bus removed with torque on for IDs {on}"
        off_since: dict[int, float] = {}
        for write in self._emulator.writes(ADDR_TORQUE_ENABLE):
            if write.value == 1:
                off_since.pop(write.dxl_id, None)
            else:
                off_since.setdefault(write.dxl_id, write.time)
        if len(off_since) < len(self._map.ids):
            return "emulated bus removed with torque off on every servo (not every torque-off write is logged)"
        return (f"emulated bus removed with torque off on every servo (off since monotonic "
                f"{max(off_since.values()):.6f} s)")


def main() -> None:
    """Console entry point ``sim_node``."""
    raise SystemExit(run(SimNode, "sim_node"))

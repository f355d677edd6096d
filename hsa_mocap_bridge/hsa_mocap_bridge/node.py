"""mocap_bridge: motion-capture PoseStamped of the platform (and base) rigid bodies → validated
planar pose ``ee_pose``.

Each platform sample goes through the check chain of ``hsa_core.sensing.mocap_gate`` (frame_id,
non-finite values, quaternion, stale/future/duplicate/out-of-order stamp against the node clock,
missing or stale base, workspace box, jump), is projected to χ_ee = [x, y, θ] in {0} by
``hsa_core.sensing.mocap`` (spec §6.1–6.2) and published with its mocap stamp in frame ``hsa_base``.
Base samples (``use_base_pose``) go through the same frame, value and stamp checks. Every drop is
counted per reason on /diagnostics and logged at most every 5 s. Parameters and topics:
docs/nodes/hsa_mocap_bridge.md.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node

from hsa_common import convert, qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report, log_level_change
from hsa_common.parameters import ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.rate_meter import RateMeter
from hsa_core.sensing import mocap
from hsa_core.sensing.mocap_gate import (
    BASE_REASONS,
    MAX_FUTURE,
    REASONS,
    BaseMode,
    GateConfig,
    Health,
    MocapGate,
    Sample,
)
from hsa_msgs.msg import PlanarPoseStamped

FRAME_ID = "hsa_base"
GAP_PERIODS = 3  # nominal mocap periods of silence reported as WARN


def _unit_quaternion(value: list[float]) -> str | None:
    """Refuse quaternions hsa_core.sensing.mocap refuses (not of unit norm)."""
    try:
        mocap.MocapConfig(base_quaternion=tuple(value))
    except ValueError as exc:
        return str(exc)
    return None


def _interval(value: list[float]) -> str | None:
    """Refuse a [low, high] pair that is empty."""
    return (
        None if value[0] < value[1] else f"must be [low, high] with low < high, got {list(value)}"
    )


SPECS = (
    ParamSpec(
        "platform_topic",
        "/mocap/platform/pose",
        "geometry_msgs/PoseStamped topic of the platform rigid body, world frame",
        read_only=True,
    ),
    ParamSpec(
        "base_topic",
        "/mocap/base/pose",
        "geometry_msgs/PoseStamped topic of the base rigid body (subscribed only if use_base_pose)",
        read_only=True,
    ),
    ParamSpec(
        "use_base_pose",
        False,
        "true: base position and orientation measured on base_topic; false: base_position "
        "parameter",
        read_only=True,
    ),
    ParamSpec(
        "base_position",
        [0.0, 0.0, 0.0],
        "[m] world position of the base markers (used if use_base_pose is false)",
        low=-100.0,
        high=100.0,
        length=3,
    ),
    ParamSpec(
        "base_quaternion",
        list(mocap.BASE_QUATERNION),
        "[-] (x, y, z, w) rotation of {0} in the world (use_base_pose false) or relative to the "
        "measured base body (true); also re-aligns the platform body frame",
        low=-1.0,
        high=1.0,
        length=4,
        validator=_unit_quaternion,
    ),
    ParamSpec(
        "base_offset",
        list(mocap.BASE_OFFSET),
        "[m] origin of {0} relative to the base markers, in {0}",
        low=-0.5,
        high=0.5,
        length=3,
    ),
    ParamSpec(
        "marker_offset",
        list(mocap.MARKER_OFFSET),
        "[m] platform pivot marker relative to the end effector, in the platform body frame",
        low=-0.5,
        high=0.5,
        length=3,
    ),
    ParamSpec(
        "mocap_rate",
        200.0,
        "[Hz] nominal mocap frame rate (jump bound, staleness warning)",
        low=1.0,
        high=2000.0,
    ),
    ParamSpec(
        "quaternion_tolerance",
        0.01,
        "[-] accepted deviation of a measured quaternion norm from 1",
        low=1e-6,
        high=0.5,
    ),
    ParamSpec(
        "frame_id",
        "world",
        "expected header frame_id of the mocap poses; any other is dropped (frame)",
        validator=lambda value: None if value else "must name a frame, not be empty",
    ),
    ParamSpec(
        "max_age",
        0.5,
        "[s] drop samples stamped more than this before the node clock; 0 disables",
        low=0.0,
        high=60.0,
    ),
    ParamSpec(
        "max_future",
        MAX_FUTURE,
        "[s] drop samples stamped more than this after the node clock",
        low=0.0,
        high=1.0,
    ),
    ParamSpec(
        "stale_timeout",
        0.25,
        "[s] diagnostics ERROR when no sample was accepted for this long",
        low=0.001,
        high=60.0,
    ),
    ParamSpec(
        "base_timeout",
        0.25,
        "[s] with use_base_pose: platform samples are dropped (base_stale) when no base "
        "sample was accepted for this long",
        low=0.001,
        high=60.0,
    ),
    ParamSpec(
        "max_jump",
        0.02,
        "[m] largest plausible EE position change per mocap period, scaled by the time since the "
        "last accepted sample; 0 disables",
        low=0.0,
        high=1.0,
    ),
    ParamSpec(
        "max_jump_angle",
        0.2,
        "[rad] largest plausible EE angle change per mocap period, scaled likewise; 0 disables",
        low=0.0,
        high=math.pi,
    ),
    ParamSpec(
        "workspace_x",
        [-0.08, 0.08],
        "[m] accepted [low, high] of the EE x in {0}",
        low=-1.0,
        high=1.0,
        length=2,
        validator=_interval,
    ),
    ParamSpec(
        "workspace_y",
        [0.06, 0.18],
        "[m] accepted [low, high] of the EE y in {0} (down the backbone)",
        low=-1.0,
        high=1.0,
        length=2,
        validator=_interval,
    ),
    ParamSpec(
        "workspace_theta",
        [-math.pi / 2, math.pi / 2],
        "[rad] accepted [low, high] of the EE angle in {0}",
        low=-math.pi,
        high=math.pi,
        length=2,
        validator=_interval,
    ),
    ParamSpec(
        "rest_check",
        False,
        "compare the first valid sample with rest_pose (robot hanging straight, phi = 0); result "
        "on /diagnostics",
        read_only=True,
    ),
    ParamSpec(
        "rest_pose",
        list(mocap.REST_POSE),
        "[m, m, rad] expected EE pose at rest",
        low=-1.0,
        high=1.0,
        length=3,
        read_only=True,
    ),
    ParamSpec(
        "rest_tolerance",
        [0.01, 0.1],
        "[m, rad] accepted position and angle deviation from rest_pose",
        low=0.0,
        high=1.0,
        length=2,
        read_only=True,
    ),
    ParamSpec(
        "diagnostics_period",
        1.0,
        "[s] period of the /diagnostics reports",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
)


def _plain(value: Any) -> Any:
    """Parameter value with arrays as plain lists."""
    return list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value


class MocapBridge(Node):
    """Projects platform poses to the plane, drops and counts implausible samples, publishes
    ``ee_pose``."""

    def __init__(self) -> None:
        super().__init__("mocap_bridge")
        self._p = declare(self, SPECS)
        self._gate: MocapGate | None = None
        self._configure()
        guard_updates(self, SPECS, self._update)
        self._counts = dict.fromkeys(("received", "published", *REASONS), 0)
        self._base_counts = dict.fromkeys(("received", "accepted", *BASE_REASONS), 0)
        self._last_rejection = self._last_base_rejection = ""
        # rest-check result: None = pending, "" = fine, else the problem
        self._rest: str | None = None
        self._level: bytes | None = None  # diagnostics level last reported
        self._base_level: bytes | None = None
        self._rates = RateMeter(self.get_clock().now().nanoseconds)
        self._pub = self.create_publisher(
            PlanarPoseStamped, "ee_pose", qos.SENSOR, qos_overriding_options=qos.overridable()
        )
        self.create_subscription(
            PoseStamped,
            self._p["platform_topic"],
            self._on_platform,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        if self._p["use_base_pose"]:
            self.create_subscription(
                PoseStamped,
                self._p["base_topic"],
                self._on_base,
                qos.SENSOR,
                qos_overriding_options=qos.overridable(),
            )
        self._diagnostics = Diagnostics(self, self._p["diagnostics_period"], hardware_id="mocap")
        self._diagnostics.add("platform", self._report)
        if self._p["use_base_pose"]:
            self._diagnostics.add("base", self._base_report)
        if self._p["rest_check"]:
            self._diagnostics.add("rest pose", self._rest_report)

    def _configure(self) -> None:
        """Build the check chain (bounds, frame chain, workspace box) from the current parameter
        values, keeping the references (newest accepted stamps, poses and arrival times) of the
        previous one."""
        p = self._p
        rate = p["mocap_rate"]  # bounds per period → speed bounds; a bound of 0 disables (→ inf)
        config = GateConfig(
            frame_id=p["frame_id"],
            quaternion_tolerance=p["quaternion_tolerance"],
            max_age=p["max_age"],
            max_future=p["max_future"],
            max_speed=p["max_jump"] * rate or math.inf,
            max_angular_speed=p["max_jump_angle"] * rate or math.inf,
            workspace=mocap.WorkspaceBox(
                tuple(p["workspace_x"]), tuple(p["workspace_y"]), tuple(p["workspace_theta"])
            ),
            base_timeout=p["base_timeout"],
            gap_timeout=GAP_PERIODS / rate,
            stale_timeout=p["stale_timeout"],
        )
        chain = mocap.MocapConfig(
            tuple(p["base_quaternion"]),
            tuple(p["base_offset"]),
            tuple(p["marker_offset"]),
            use_base_orientation=p["use_base_pose"],
        )
        if self._gate is None:
            self._gate = MocapGate(config, chain, tuple(p["base_position"]))
        else:
            self._gate.reconfigure(config, chain, tuple(p["base_position"]))

    def _update(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time parameter updates."""
        self._p.update({name: _plain(value) for name, value in changes.items()})
        self._configure()

    def _on_base(self, msg: PoseStamped) -> None:
        """Check one base sample; the gate keeps the newest accepted one."""
        self._base_counts["received"] += 1
        now = self.get_clock().now().nanoseconds
        mode = self._gate.base_mode(now)
        verdict = self._gate.base_sample(_sample(msg), now)
        if verdict.reason is not None:
            self._base_counts[verdict.reason] += 1
            self._last_base_rejection = f"{verdict.reason}: {verdict.text}"
            self.get_logger().warning(
                f"dropped base sample ({self._last_base_rejection}); counts on /diagnostics",
                throttle_duration_sec=5.0,
            )
            return
        if mode is not BaseMode.LIVE:
            self.get_logger().info(
                f"receiving base poses on {self._p['base_topic']}"
                + (" again: platform poses used again" if mode is BaseMode.STALE else "")
            )
        self._base_counts["accepted"] += 1

    def _on_platform(self, msg: PoseStamped) -> None:
        """Check, project and publish one platform sample, or count why it was dropped."""
        self._counts["received"] += 1
        now = self.get_clock().now().nanoseconds
        first = self._gate.last_at_ns is None
        verdict = self._gate.check(_sample(msg), now)
        if verdict.reason is not None:
            self._counts[verdict.reason] += 1
            self._last_rejection = f"{verdict.reason}: {verdict.text}"
            self.get_logger().warning(
                f"dropped platform sample ({self._last_rejection}); counts on /diagnostics",
                throttle_duration_sec=5.0,
            )
            return
        if self._p["rest_check"] and self._rest is None:
            self._check_rest(verdict.chiee)
        if first:
            self.get_logger().info(f"receiving platform poses on {self._p['platform_topic']}")
        out = PlanarPoseStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = FRAME_ID
        out.pose = convert.planar_pose_msg(verdict.chiee)
        self._pub.publish(out)
        self._counts["published"] += 1

    def _check_rest(self, chiee: np.ndarray) -> None:
        """Start-up check of the sign chain on the first valid sample; the result goes to
        /diagnostics."""
        position_tol, angle_tol = self._p["rest_tolerance"]
        self._rest = (
            mocap.rest_pose_problem(chiee, self._p["rest_pose"], position_tol, angle_tol) or ""
        )
        if self._rest:
            self.get_logger().error(f"rest-pose check failed: {self._rest}")
        else:
            self.get_logger().info(f"rest-pose check passed: {np.round(chiee, 4).tolist()}")

    def _report(self) -> Report:
        """Platform stream health, counts per drop reason, rates and the age of the newest accepted
        sample."""
        now = self.get_clock().now().nanoseconds
        counts = {name: self._counts[name] for name in ("received", "published")}
        rates = self._rates.rates(now, counts)
        values: dict[str, object] = {
            **counts,
            **{f"rejected_{reason}": self._counts[reason] for reason in REASONS},
            "input_rate_hz": round(rates["received"], 1),
            "output_rate_hz": round(rates["published"], 1),
            "last_rejection": self._last_rejection,
            "clock_resets": self._gate.time_resets,
        }
        health = self._gate.health(now)
        if health is not Health.WAITING:
            values["time_since_last_sample_s"] = round(self._gate.silence(now), 4)
            values["last_sample_age_s"] = round((now - self._gate.last_stamp_ns) * 1e-9, 4)
        level, message = {
            Health.WAITING: (WARN, "no valid platform pose yet"),
            Health.LIVE: (OK, "publishing ee_pose"),
            Health.GAP: (WARN, f"no valid platform pose for {self._gate.silence(now):.3g} s"),
            Health.STALE: (
                ERROR,
                f"stale: no valid platform pose for {self._gate.silence(now):.3g} s",
            ),
        }[health]
        self._level = log_level_change(self.get_logger(), self._level, level, message)
        return Report(level, message, values)

    def _base_report(self) -> Report:
        """Base mode (waiting, live, stale), counts per drop reason and the silence of the base
        stream."""
        now = self.get_clock().now().nanoseconds
        mode = self._gate.base_mode(now)
        values: dict[str, object] = {
            "mode": mode.value,
            "received": self._base_counts["received"],
            "accepted": self._base_counts["accepted"],
            **{f"rejected_{reason}": self._base_counts[reason] for reason in BASE_REASONS},
            "last_rejection": self._last_base_rejection,
        }
        if mode is not BaseMode.WAITING:
            values["time_since_last_base_s"] = round(self._gate.base_age(now), 4)
        level, message = {
            BaseMode.WAITING: (
                WARN,
                "waiting: no valid base pose yet, platform poses dropped (no_base)",
            ),
            BaseMode.LIVE: (OK, "live: measured base pose in use"),
            BaseMode.STALE: (
                ERROR,
                f"stale: no valid base pose for {self._gate.base_age(now):.3g} s, platform "
                "poses dropped (base_stale)",
            ),
        }[mode]
        self._base_level = log_level_change(self.get_logger(), self._base_level, level, message)
        return Report(level, message, values)

    def _rest_report(self) -> Report:
        """Result of the start-up rest-pose check."""
        if self._rest is None:
            return Report(WARN, "waiting for the first valid sample", {})
        return (
            Report(ERROR, self._rest, {}) if self._rest else Report(OK, "rest pose as expected", {})
        )


def _sample(msg: PoseStamped) -> Sample:
    """The check-chain sample of a PoseStamped: stamp [ns], frame_id, position (x, y, z), quaternion
    (x, y, z, w)."""
    return Sample(
        convert.stamp_ns(msg.header.stamp), msg.header.frame_id, *convert.position_quaternion(msg)
    )


def main() -> None:
    """Console script ``mocap_bridge``."""
    raise SystemExit(run(MocapBridge, "mocap_bridge"))

"""marker_node: RViz/Foxglove markers of the robot (``state``) and of the goal (``setpoint``) →
``markers``.

One visualization_msgs/MarkerArray per accepted ``state``, at most ``rate`` per second of the node
clock (the states in between are dropped before any work is done): backbone and both rods as
LINE_STRIPs, the platform as a CUBE, and once a setpoint is known the desired EE position as a
SPHERE and a translucent ghost of q^d (backbone, rods, platform outline). A new setpoint is drawn at
once. Every marker carries the stamp of the newest state and the ``frame_id`` parameter; namespaces
and ids never change, so each marker is replaced in place. All geometry comes from
hsa_core.model.visual. Parameters and topics: docs/nodes/hsa_kinematics_node.md.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from rclpy.node import Node
from rclpy.time import Time
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from hsa_common import convert, qos
from hsa_common.diagnostics import OK, WARN, Diagnostics, Report
from hsa_common.drawing_params import DRAWING_SPECS
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.visual import RobotGeometry, geometry_fn
from hsa_core.rate_meter import RateMeter
from hsa_msgs.msg import CsConfiguration, PlanarState, Setpoint

SPECS = (
    *MODEL_SPECS,
    ParamSpec(
        "frame_id", "hsa_base", "frame of the markers (the planar base frame {0})", read_only=True
    ),
    ParamSpec(
        "rate",
        20.0,
        "[Hz] most MarkerArrays per second (node clock); states in between are dropped",
        low=0.1,
        high=1000.0,
    ),
    *DRAWING_SPECS,
    ParamSpec(
        "diagnostics_period",
        1.0,
        "[s] period of the /diagnostics reports",
        low=0.05,
        high=60.0,
        read_only=True,
    ),
)

NAMESPACES = ("backbone", "rods", "platform", "setpoint", "ghost")
"""Marker namespaces; ids: backbone 0, rods 0/1 (virtual rod 1/2), platform 0, setpoint 0, ghost
0-3."""

BACKBONE = (0.9, 0.9, 0.9)
RODS = ((0.85, 0.33, 0.10), (0.00, 0.45, 0.74))  # virtual rod 1 (roff < 0), rod 2 (roff > 0)
PLATFORM = (0.55, 0.55, 0.6)
SETPOINT = (0.15, 0.8, 0.15)
GHOST = (0.3, 0.8, 1.0)


class MarkerNode(Node):
    """Draws the measured configuration and the setpoint with hsa_core.model.visual geometry,
    rate-limited."""

    def __init__(self) -> None:
        super().__init__("marker_node")
        self._p = declare(self, SPECS)
        self._params = load_model(self._p)
        self._geometry = geometry_fn(self._params, self._p["n_points"])
        self._compute(CsConfiguration(sigma_ax=0.0))  # JIT-compile now, not on the first state
        self._rod_width = float(2.0 * np.max(np.asarray(self._params.r_out)))
        self._plate_size = np.asarray(self._params.platform_size, dtype=float)
        guard_updates(self, SPECS, self._update)
        self._state: PlanarState | None = None
        self._setpoint: Setpoint | None = None
        self._goal: list[
            Marker
        ] = []  # setpoint sphere and ghost of q^d, rebuilt on a new setpoint or parameter
        self._published_at: Time | None = None
        self._counts = {"states": 0, "setpoints": 0, "published": 0}
        self._rates = RateMeter(self.get_clock().now().nanoseconds)
        self._pub = self.create_publisher(
            MarkerArray, "markers", qos.INFO, qos_overriding_options=qos.overridable()
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
            qos_overriding_options=qos.overridable(),
        )
        self._diagnostics = Diagnostics(self, self._p["diagnostics_period"])
        self._diagnostics.add("markers", self._report)

    def _update(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time updates; the goal markers are redrawn with them."""
        self._p.update(changes)
        if self._setpoint is not None:
            self._goal = self._goal_markers(self._setpoint)

    def _compute(self, q: CsConfiguration) -> RobotGeometry:
        """Geometry of configuration q as NumPy arrays."""
        return jax.device_get(self._geometry(convert.configuration(q)))

    def _on_state(self, msg: PlanarState) -> None:
        """Keep the newest state; draw it unless the last MarkerArray went out less than 1/rate
        ago."""
        self._counts["states"] += 1
        self._state = msg
        now = self.get_clock().now()
        if (
            self._published_at is not None
            and 0 <= (now - self._published_at).nanoseconds < 1e9 / self._p["rate"]
        ):
            return
        self._publish(now)

    def _on_setpoint(self, msg: Setpoint) -> None:
        """Rebuild the goal markers and draw them at once."""
        self._counts["setpoints"] += 1
        self._setpoint = msg
        self._goal = self._goal_markers(msg)
        self._publish(self.get_clock().now())

    def _publish(self, now: Time) -> None:
        """One MarkerArray: robot of the newest state, setpoint sphere and ghost, all stamped with
        the state stamp."""
        markers: list[Marker] = []
        stamp = self._state.header.stamp if self._state is not None else self._setpoint.header.stamp
        if self._state is not None:
            markers += self._robot_markers("", self._compute(self._state.q), ghost=False)
        markers += self._goal
        for marker in markers:
            marker.header.stamp = stamp
            marker.header.frame_id = self._p["frame_id"]
        self._pub.publish(MarkerArray(markers=markers))
        self._published_at = now
        self._counts["published"] += 1

    def _goal_markers(self, setpoint: Setpoint) -> list[Marker]:
        """SPHERE at the desired EE position and the translucent ghost of q^d."""
        goal = setpoint.chiee_des
        sphere = _marker("setpoint", 0, Marker.SPHERE, SETPOINT, 1.0)
        sphere.pose.position = convert.planar_point(goal.x, goal.y)
        sphere.scale.x = sphere.scale.y = sphere.scale.z = self._p["setpoint_diameter"]
        return [sphere, *self._robot_markers("ghost", self._compute(setpoint.q_des), ghost=True)]

    def _robot_markers(self, ns: str, g: RobotGeometry, ghost: bool) -> list[Marker]:
        """Backbone and rod LINE_STRIPs plus the platform (CUBE for the robot, outline LINE_STRIP
        for the ghost)."""
        alpha = self._p["ghost_alpha"] if ghost else 1.0

        def strip(
            name: str, marker_id: int, points: np.ndarray, color: tuple[float, ...], width: float
        ) -> Marker:
            marker = _marker(
                ns or name, marker_id, Marker.LINE_STRIP, GHOST if ghost else color, alpha
            )
            marker.scale.x = width
            marker.points = [convert.planar_point(x, y) for x, y in points]
            return marker

        backbone_width = self._p["backbone_width"]
        markers = [
            strip("backbone", 0, g.backbone, BACKBONE, backbone_width),
            strip("rods", 1 if ghost else 0, g.rods[0], RODS[0], self._rod_width),
            strip("rods", 2 if ghost else 1, g.rods[1], RODS[1], self._rod_width),
        ]
        if ghost:
            markers.append(strip("platform", 3, g.platform, PLATFORM, backbone_width))
            return markers
        cube = _marker("platform", 0, Marker.CUBE, PLATFORM, 1.0)
        cube.pose.position = convert.planar_point(*g.platform_pose[:2])
        orientation = cube.pose.orientation
        orientation.x, orientation.y, orientation.z, orientation.w = (
            float(v) for v in g.platform_orientation
        )
        cube.scale.x, cube.scale.y, cube.scale.z = (float(v) for v in self._plate_size)
        return markers + [cube]

    def _report(self) -> Report:
        """Counts and output rate since the last report; WARN while no state has arrived."""
        now = self.get_clock().now()
        rate = self._rates.rates(now.nanoseconds, {"published": self._counts["published"]})[
            "published"
        ]
        values: dict[str, Any] = {
            **self._counts,
            "output_rate_hz": round(rate, 1),
            "rate_limit_hz": self._p["rate"],
        }
        if self._state is None:
            return Report(WARN, "waiting for state", values)
        return Report(OK, "drawing", values)


def _marker(ns: str, marker_id: int, kind: int, rgb: tuple[float, ...], alpha: float) -> Marker:
    """An ADD marker with identity orientation and the given colour."""
    marker = Marker(ns=ns, id=marker_id, type=kind, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.color = ColorRGBA(r=rgb[0], g=rgb[1], b=rgb[2], a=float(alpha))
    return marker


def main() -> None:
    """Console script ``marker_node``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(MarkerNode, "marker_node"))

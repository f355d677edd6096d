"""live_node: the running graph served to Foxglove over WebSocket on 127.0.0.1 (foxglove-sdk), no
ROS desktop needed.

Subscribes ``state``, ``setpoint``, ``controller_info``, ``phi_present``, ``sequencer_status`` and
``/diagnostics`` and logs them on Foxglove channels (docs/nodes/hsa_live.md):

* ``/live/scene`` (foxglove.SceneUpdate): entity ``robot`` (backbone and rod LINE strips, the
  platform as a cube) of the newest state, at most ``scene_rate`` per second of the steady (wall)
  clock, whatever the simulation speed; entity ``goal`` (setpoint sphere and a translucent ghost of
  q^d) once a setpoint is known, redrawn at once on a new setpoint. Geometry from
  hsa_core.model.visual.
* ``/live/tracking``, ``/live/actuation``, ``/live/configuration`` (JSON, one message per controller
  tick): p_ee and p^d with e and ‖e‖; φ commanded, before saturation, φ^ss and the admissible box; q
  and q^d. ``/live/phi_present`` (JSON): the measured φ at the driver rate. The log time of each
  message is the stamp of the ROS message it comes from, so the plots run on the graph's clock.
* ``/live/diagnostics`` and ``/live/progress`` (JSON, every ``progress_period`` of the steady clock
  and on a sequencer change): the newest status of every diagnostic name (STALE when silent for
  ``diagnostics_stale`` s of wall time, so a stalled simulation shows), and "step k/n · mode · ‖e‖".

Nothing is computed for a channel no viewer subscribes to. The server binds 127.0.0.1 only; the port
is a parameter.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import foxglove
import jax
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from foxglove.channels import SceneUpdateChannel
from foxglove.messages import SceneEntity, SceneUpdate, Timestamp
from foxglove.websocket import ChannelView, Client
from rclpy.node import Node
from std_msgs.msg import String

from hsa_common import convert, lockstep, qos
from hsa_common.diagnostics import OK, WARN, Diagnostics, Report
from hsa_common.drawing_params import DRAWING_SPECS
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.analysis import live
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.visual import RobotGeometry, geometry_fn
from hsa_live import scene
from hsa_msgs.msg import ControllerInfo, PlanarActuation, PlanarState, Setpoint

HOST = "127.0.0.1"
"""The only address the server binds: the live view is for this machine (tunnel it, e.g. ssh -L, to
look remotely)."""

SPECS = (
    *MODEL_SPECS,
    ParamSpec(
        "port",
        8765,
        "[-] TCP port of the Foxglove WebSocket server on 127.0.0.1 (0 = any free port, logged)",
        low=0,
        high=65535,
        read_only=True,
    ),
    ParamSpec(
        "scene_rate",
        25.0,
        "[Hz] most SceneUpdates per second of wall time; states in between are not drawn",
        low=1.0,
        high=60.0,
    ),
    ParamSpec(
        "frame_id",
        "hsa_base",
        "frame of the scene entities (the planar base frame {0})",
        read_only=True,
    ),
    *DRAWING_SPECS,
    ParamSpec(
        "progress_period",
        1.0,
        "[s] wall-time period of /live/progress and /live/diagnostics (late viewers get them)",
        low=0.1,
        high=60.0,
        read_only=True,
    ),
    ParamSpec(
        "diagnostics_stale",
        5.0,
        "[s] a diagnostic status not refreshed for this long (wall time) is shown STALE",
        low=0.5,
        high=600.0,
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


class _Subscribers:
    """Counts viewer subscriptions per channel (called from the server's threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.by_topic: dict[str, int] = {}

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        """One more viewer on ``channel``."""
        with self._lock:
            self.by_topic[channel.topic] = self.by_topic.get(channel.topic, 0) + 1

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        """One viewer fewer on ``channel`` (also on disconnect)."""
        with self._lock:
            self.by_topic[channel.topic] = max(0, self.by_topic.get(channel.topic, 0) - 1)

    def total(self) -> int:
        """Subscriptions over all channels."""
        with self._lock:
            return sum(self.by_topic.values())


class LiveNode(Node):
    """Forwards the graph to Foxglove channels; the scene is throttled (wall time), the plots go per
    controller tick."""

    def __init__(self) -> None:
        super().__init__("live_node")
        self._p = declare(self, SPECS)
        self._params = load_model(self._p)
        # bind first: a taken port is refused before seconds of JIT compilation
        self._viewers = _Subscribers()
        self._fox = foxglove.Context()
        self._scene = SceneUpdateChannel("/live/scene", context=self._fox)
        self._json = {
            topic: foxglove.Channel(topic, schema=schema, context=self._fox)
            for topic, schema in _schemas().items()
        }
        try:
            self._server = foxglove.start_server(
                name="hsa_live",
                host=HOST,
                port=self._p["port"],
                server_listener=self._viewers,
                context=self._fox,
            )
        except RuntimeError as exc:  # port taken, or not a port this user may bind
            raise ParameterValidationError(
                f"parameter 'port': cannot serve on {HOST}:{self._p['port']}: {exc}"
            ) from exc
        self._geometry = geometry_fn(self._params, self._p["n_points"])
        self._compute(np.zeros(3))  # JIT-compile now, not on the first state
        self._phi_box = tuple(np.asarray(b, dtype=float) for b in self._params.phi_limit.box)
        self._throttle = live.Throttle(self._p["scene_rate"])
        self._table = live.DiagnosticsTable(self._p["diagnostics_stale"])
        self._style = self._drawing_style()
        guard_updates(self, SPECS, self._update)
        self._goal: SceneEntity | None = None
        self._setpoint: Setpoint | None = None
        self._sequencer: str | None = None
        self._controller_state: int | None = None
        self._e_norm: float | None = None
        self._counts = {"states": 0, "scenes": 0, "ticks": 0, "phi_present": 0, "diagnostics": 0}
        self.get_logger().info(
            f"Foxglove live view on ws://{HOST}:{self._server.port} (layout: "
            "share/hsa_live/config/foxglove_layout.json)"
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
        self.create_subscription(
            ControllerInfo,
            "controller_info",
            self._on_info,
            qos.INFO,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(
            PlanarActuation,
            "phi_present",
            self._on_phi_present,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(
            String,
            "sequencer_status",
            self._on_sequencer,
            qos.LATCHED,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        # on the steady clock, outside the lockstep barrier: runs on while simulated time stands
        lockstep.wall_timer(self, self._p["progress_period"], self._publish_status)
        self._diagnostics = Diagnostics(self, self._p["diagnostics_period"])
        self._diagnostics.add("live view", self._report)

    def _update(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time updates (scene rate, drawing sizes, stale limit)."""
        self._p.update(changes)
        self._style = self._drawing_style()
        self._throttle.rate = self._p["scene_rate"]
        self._table.stale_after = self._p["diagnostics_stale"]
        if self._setpoint is not None:
            self._on_setpoint(self._setpoint)  # the goal redrawn with the new sizes

    def _drawing_style(self) -> scene.Style:
        """Sizes and opacity of the scene from the parameters and the model (rod width = 2
        r_out)."""
        return scene.Style(
            self._p["frame_id"],
            self._p["backbone_width"],
            float(2.0 * np.max(np.asarray(self._params.r_out))),
            tuple(float(v) for v in np.asarray(self._params.platform_size)),
            self._p["setpoint_diameter"],
            self._p["ghost_alpha"],
        )

    def _compute(self, q: np.ndarray) -> RobotGeometry:
        """Geometry of configuration q as NumPy arrays."""
        return jax.device_get(self._geometry(np.asarray(q, dtype=float)))

    # --- scene
    # ----------------------------------------------------------------------------------------------

    def _on_state(self, msg: PlanarState) -> None:
        """Draw the newest state unless the last scene went out less than 1/scene_rate ago or nobody
        watches."""
        self._counts["states"] += 1
        if not self._scene.has_sinks() or not self._throttle.due(time.monotonic_ns()):
            return
        robot = scene.robot_entity(
            self._compute(convert.configuration(msg.q)), _stamp(msg.header.stamp), self._style
        )
        self._log_scene(
            [robot, *([self._goal] if self._goal is not None else [])],
            convert.stamp_ns(msg.header.stamp),
        )

    def _on_setpoint(self, msg: Setpoint) -> None:
        """Rebuild the goal entity and send it at once."""
        self._setpoint = msg
        self._goal = scene.goal_entity(
            self._compute(convert.configuration(msg.q_des)),
            convert.planar_pose(msg.chiee_des)[:2],
            _stamp(msg.header.stamp),
            self._style,
        )
        if self._scene.has_sinks():
            self._log_scene([self._goal], convert.stamp_ns(msg.header.stamp))

    def _log_scene(self, entities: list[SceneEntity], log_time: int) -> None:
        """One SceneUpdate with the given entities."""
        self._scene.log(SceneUpdate(entities=entities), log_time=log_time)
        self._counts["scenes"] += 1

    # --- plots
    # ----------------------------------------------------------------------------------------------

    def _on_info(self, msg: ControllerInfo) -> None:
        """One tracking, actuation and configuration message per controller tick."""
        self._counts["ticks"] += 1
        self._controller_state = int(msg.state)
        sample = live.tracking_sample(
            convert.planar_pose(msg.chiee)[:2], convert.planar_pose(msg.chiee_des)[:2]
        )
        self._e_norm = sample.get("e_norm")
        t = convert.stamp_ns(msg.header.stamp)
        self._log("/live/tracking", sample, t)
        self._log(
            "/live/actuation",
            lambda: live.actuation_sample(
                msg.phi_des_sat, msg.phi_des_unsat, msg.phi_ss, *self._phi_box, msg.saturated
            ),
            t,
        )
        self._log(
            "/live/configuration",
            lambda: live.configuration_sample(
                convert.configuration(msg.q), convert.configuration(msg.q_des)
            ),
            t,
        )

    def _on_phi_present(self, msg: PlanarActuation) -> None:
        """The measured twist from the driver."""
        self._counts["phi_present"] += 1
        self._log(
            "/live/phi_present",
            lambda: live.phi_present_sample(msg.phi),
            convert.stamp_ns(msg.header.stamp),
        )

    def _log(self, topic: str, payload: Any, log_time: int) -> None:
        """Log a JSON payload (or a function making it, called only when a viewer subscribes) on
        ``topic``."""
        channel = self._json[topic]
        if channel.has_sinks():
            channel.log(payload() if callable(payload) else payload, log_time=log_time)

    # --- diagnostics and progress
    # ----------------------------------------------------------------------------------

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Keep the newest status of every name."""
        self._counts["diagnostics"] += 1
        now = time.monotonic()
        for status in msg.status:
            self._table.update(status.name, _level(status.level), status.message, now)

    def _on_sequencer(self, msg: String) -> None:
        """A new sequencer status: send the progress at once."""
        self._sequencer = msg.data
        self._log(
            "/live/progress",
            lambda: live.progress(self._sequencer, self._controller_state, self._e_norm),
            self.get_clock().now().nanoseconds,
        )

    def _publish_status(self) -> None:
        """Progress and the diagnostics table, every progress_period."""
        now = self.get_clock().now().nanoseconds
        self._log(
            "/live/progress",
            lambda: live.progress(self._sequencer, self._controller_state, self._e_norm),
            now,
        )
        self._log("/live/diagnostics", lambda: self._table.snapshot(time.monotonic()), now)

    def _report(self) -> Report:
        """Port, viewer subscriptions and what was forwarded; WARN while no viewer is subscribed."""
        viewers = self._viewers.total()
        values = {
            "url": f"ws://{HOST}:{self._server.port}",
            "subscriptions": viewers,
            **self._counts,
            "scene_rate_limit_hz": self._p["scene_rate"],
        }
        if viewers == 0:
            return Report(WARN, "serving, no viewer subscribed", values)
        return Report(OK, f"serving {viewers} subscriptions", values)

    def on_shutdown(self) -> None:
        """Close the WebSocket server (viewers see the connection end)."""
        self._server.stop()


def _schemas() -> dict[str, dict[str, Any]]:
    """JSON schema of every JSON channel, from a representative payload."""
    pair, triple = [0.0, 0.0], [0.0, 0.0, 0.0]
    table = live.DiagnosticsTable(1.0)
    table.update("node: check", 0, "", 0.0)
    return {
        "/live/tracking": live.json_schema("hsa_live.Tracking", live.tracking_sample(pair, pair)),
        "/live/actuation": live.json_schema(
            "hsa_live.Actuation", live.actuation_sample(pair, pair, pair, pair, pair, False)
        ),
        "/live/configuration": live.json_schema(
            "hsa_live.Configuration", live.configuration_sample(triple, triple)
        ),
        "/live/phi_present": live.json_schema("hsa_live.PhiPresent", live.phi_present_sample(pair)),
        "/live/diagnostics": live.json_schema("hsa_live.Diagnostics", table.snapshot(0.0)),
        "/live/progress": live.json_schema(
            "hsa_live.Progress",
            live.progress(
                json.dumps(
                    {
                        "state": "",
                        "trajectory": "",
                        "setpoint_index": 0,
                        "length": 1,
                        "finished": False,
                        "failures": 0,
                    }
                ),
                0,
                0.0,
            ),
        ),
    }


def _level(level: bytes | int) -> int:
    """DiagnosticStatus level as an int (rclpy gives a one-byte bytes)."""
    return level if isinstance(level, int) else level[0]


def _stamp(stamp: Any) -> Timestamp:
    """Foxglove Timestamp of a builtin_interfaces Time."""
    return Timestamp(int(stamp.sec), int(stamp.nanosec))


def main() -> None:
    """Console script ``live_node``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(LiveNode, "live_node"))

"""setpoint_sequencer: plays a reference trajectory through the `plan_setpoint` service and
publishes `setpoint`.

Schedule: point j is requested at t0 + j/rate (or t0 + times[j]), where t0 (t = 0) is when the
answer for point 0 arrived, i.e. when the first setpoint was published. Calls are asynchronous (a
done-callback handles the answer, nothing spins inside a callback), with the service QoS
hsa_common.qos.SERVICE. A failed or timed-out plan is counted, reported on `sequencer_status` and
logged (at most every 5 s); the previous setpoint stays active. After the last point's slot the last
setpoint is held and `finished` is reported; with `exit_on_finish` the process exits `finish_hold`
seconds later so a launch file can end the graph.
"""

from __future__ import annotations

import json
from typing import Any

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.task import Future
from rclpy.time import Time
from rclpy.timer import Timer
from std_msgs.msg import String

from hsa_common import qos
from hsa_common.diagnostics import OK, WARN, Diagnostics, Report
from hsa_common.model_params import MODEL_SPECS
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.task import trajectories
from hsa_core.task.sequencer_timing import SUPERVISION_PERIOD_NS
from hsa_core.task.trajectories import TimedReference
from hsa_msgs.msg import Setpoint
from hsa_msgs.srv import PlanSetpoint

TRAJECTORIES = ("steps", "star", "circle", "contour")
PLANNER_CODES = {
    "default": PlanSetpoint.Request.PLANNER_DEFAULT,
    "static": PlanSetpoint.Request.PLANNER_STATIC,
    "rollout": PlanSetpoint.Request.PLANNER_ROLLOUT,
}


def _check_points(value: Any) -> str | None:
    """Unset/empty, or a flat list of x, y pairs."""
    if value is None or len(value) == 0 or len(value) % 2 == 0:
        return None
    return f"must be a flat list [x0, y0, x1, y1, ...] of even length, got {len(value)} values"


SPECS = (
    MODEL_SPECS[0],
    ParamSpec("trajectory", "steps", "reference to play", choices=TRAJECTORIES, read_only=True),
    ParamSpec(
        "points",
        Parameter.Type.DOUBLE_ARRAY,
        "[m] steps only: custom EE positions [x0, y0, x1, y1, ...] in hsa_base (unset or empty = "
        "the material's step list of experiments.md §2)",
        read_only=True,
        validator=_check_points,
    ),
    ParamSpec(
        "times",
        Parameter.Type.DOUBLE_ARRAY,
        "[s] steps with 'points' only: the instant of each point after point 0 (0 first, "
        "increasing; e.g. a real run's step instants); the last point lasts 1/rate; unset or empty "
        "= every 1/rate",
        read_only=True,
    ),
    ParamSpec(
        "rate",
        0.0,
        "[Hz] setpoint rate (0 = the experiments' rate: 0.1 Hz for steps, 8 Hz otherwise)",
        low=0.0,
        high=100.0,
        read_only=True,
    ),
    ParamSpec(
        "start_delay",
        0.0,
        "[s] wait after the planner service is available before the first point",
        low=0.0,
        high=3600.0,
        read_only=True,
    ),
    ParamSpec(
        "loop",
        False,
        "restart from the first point after the last instead of finishing",
        read_only=True,
    ),
    ParamSpec(
        "exit_on_finish",
        False,
        "exit the process (code 0) finish_hold seconds after finishing",
        read_only=True,
    ),
    ParamSpec(
        "finish_hold",
        0.0,
        "[s] how long the finished sequencer stays up before exit_on_finish exits",
        low=0.0,
        high=3600.0,
        read_only=True,
    ),
    ParamSpec(
        "planner",
        "default",
        "planner requested for every point",
        choices=tuple(PLANNER_CODES),
        read_only=True,
    ),
    ParamSpec(
        "plan_timeout",
        5.0,
        "[s] a plan not answered within this time is reported as failed",
        low=0.01,
        high=600.0,
        read_only=True,
    ),
    ParamSpec(
        "centroid",
        [0.0, 0.1285],
        "[m] star/circle/contour: centre of the shape in hsa_base",
        length=2,
        read_only=True,
    ),
    ParamSpec(
        "radius",
        0.013,
        "[m] star/circle: outer radius; contour: r_max",
        low=1e-4,
        high=0.1,
        read_only=True,
    ),
    ParamSpec(
        "max_radius",
        trajectories.R_MAX_SAFE,
        "[m] largest accepted radius (raise deliberately only)",
        low=1e-4,
        high=0.1,
        read_only=True,
    ),
    ParamSpec(
        "n_points",
        0,
        "[-] star/circle: points on the outline (0 = 500 for the star, 200 for the circle)",
        low=0,
        high=100000,
        read_only=True,
    ),
    ParamSpec(
        "direction",
        "traced",
        "order of the points: 'traced' (contour: as OpenCV traces it; star/circle: "
        "ccw), 'ccw' or 'cw' in hsa_base",
        choices=("traced", "ccw", "cw"),
        read_only=True,
    ),
    ParamSpec("image_path", "", "contour: image file of a closed shape", read_only=True),
    ParamSpec(
        "image_threshold",
        140,
        "[grey level] contour: binarisation threshold",
        low=0,
        high=255,
        read_only=True,
    ),
    ParamSpec(
        "image_invert", True, "contour: the shape is dark on a light background", read_only=True
    ),
    ParamSpec(
        "image_crop_square",
        False,
        "contour: crop a centred square first (the star asset)",
        read_only=True,
    ),
    ParamSpec(
        "image_flip",
        False,
        "contour: multiply the normalised contour by -1 (flame, CSAIL, bat assets)",
        read_only=True,
    ),
    ParamSpec(
        "contour_k",
        5,
        "[-] contour: keep every k-th contour point",
        low=1,
        high=10000,
        read_only=True,
    ),
)


def build_reference(v: dict[str, Any]) -> TimedReference:
    """The TimedReference the parameters describe (raises ParameterValidationError naming the
    problem)."""
    kind = v["trajectory"]
    if v["points"] and kind != "steps":
        raise ParameterValidationError(
            f"parameter 'points' applies to trajectory 'steps' only, not '{kind}'"
        )
    if v["times"] and not v["points"]:
        raise ParameterValidationError(
            "parameter 'times' applies to trajectory 'steps' with 'points' only"
        )
    if kind == "contour" and not v["image_path"]:
        raise ParameterValidationError(
            "parameter 'image_path' must name an image for trajectory 'contour'"
        )
    rate = v["rate"] or (
        1.0 / trajectories.STEP_PERIOD if kind == "steps" else trajectories.CONTOUR_RATE
    )
    shape_direction = "ccw" if v["direction"] == "traced" else v["direction"]
    shape = {
        "centroid": v["centroid"],
        "radius": v["radius"],
        "rate": rate,
        "direction": shape_direction,
        "max_radius": v["max_radius"],
    }
    try:
        if kind == "steps":
            points = (
                list(zip(v["points"][::2], v["points"][1::2])) if v["points"] else v["material"]
            )
            steps = trajectories.step_reference(points, period=1.0 / rate)
            if not v["times"]:
                return steps
            if len(v["times"]) != len(steps) or v["times"][0] != 0.0:
                raise ValueError(
                    f"'times' needs one instant per point ({len(steps)}), the first 0, got "
                    f"{len(v['times'])} starting at {v['times'][0]:g}"
                )
            return trajectories.TimedReference(
                v["times"], steps.p_des, steps.name, v["times"][-1] + 1.0 / rate
            )
        if kind == "circle":
            return trajectories.circle_reference(**shape, n_points=v["n_points"] or 200)
        if kind == "star":
            return trajectories.star_reference(**shape, n_points=v["n_points"] or 500)
        return trajectories.contour_reference(
            v["image_path"],
            centroid=v["centroid"],
            r_max=v["radius"],
            k=v["contour_k"],
            rate=rate,
            threshold=v["image_threshold"],
            invert=v["image_invert"],
            crop_square=v["image_crop_square"],
            flip=v["image_flip"],
            direction=v["direction"],
            max_radius=v["max_radius"],
        )
    except (ValueError, OSError) as exc:
        raise ParameterValidationError(f"parameters of trajectory '{kind}' refused: {exc}") from exc


class SetpointSequencer(Node):
    """Requests one plan per reference point on schedule and publishes each successful one as the
    active setpoint."""

    def __init__(self) -> None:
        """Declare parameters, build the reference, create the client, publishers and the
        supervision timer."""
        super().__init__("setpoint_sequencer")
        self._p = declare(self, SPECS)
        guard_updates(self, SPECS)
        self._ref = build_reference(self._p)
        self._n = len(self._ref)
        self._period = self._ref.duration / self._n
        # continuous references warm-start (§2.1)
        self._warm_start = self._p["trajectory"] != "steps"
        self._client = self.create_client(PlanSetpoint, "plan_setpoint", qos_profile=qos.SERVICE)
        self._setpoint_pub = self.create_publisher(
            Setpoint, "setpoint", qos.LATCHED, qos_overriding_options=qos.overridable()
        )
        self._status_pub = self.create_publisher(
            String, "sequencer_status", qos.LATCHED, qos_overriding_options=qos.overridable()
        )
        self._state = "waiting_for_service"
        self._k = 0  # schedule tick: point k % n
        self._t0: Time | None = None
        self._start_at: Time | None = None
        self._finished_at: Time | None = None
        self._schedule_done = False
        self._pending: dict[int, tuple[Future, Time]] = {}
        self._index = -1
        self._setpoint_index = -1
        self._published = 0
        self._failures = 0
        self._last_failure: dict[str, Any] | None = None
        self._max_latency = 0.0
        self._tick_timer: Timer | None = None
        self.create_timer(SUPERVISION_PERIOD_NS / 1e9, self._supervise)
        diagnostics = Diagnostics(self)
        diagnostics.add("sequence", self._report)
        self._publish_status()
        self.get_logger().info(
            f"{self._ref.name}: {self._n} points every {self._period:g} s; waiting for service "
            f"'{self._client.srv_name}'"
        )

    def _supervise(self) -> None:
        """Wait for the service and the start delay, time out unanswered plans, end the process
        after finishing."""
        now = self.get_clock().now()
        if self._state == "waiting_for_service":
            if self._client.service_is_ready():
                self._start_at = now + _duration(self._p["start_delay"])
                self._set_state("delay")
                self.get_logger().info(
                    f"service available; first point in {self._p['start_delay']:g} s"
                )
        elif self._state == "delay":
            if now >= self._start_at:
                self._set_state("running")
                self._send(0)
        elif self._state == "running":
            for k, (future, sent) in list(self._pending.items()):
                if (now - sent).nanoseconds * 1e-9 > self._p["plan_timeout"]:
                    self._client.remove_pending_request(future)
                    del self._pending[k]
                    self._fail(
                        k,
                        "TIMEOUT",
                        f"no answer from the planner within {self._p['plan_timeout']:g} s",
                    )
                    self._after_answer(now, k)
        elif self._p["exit_on_finish"] and now >= self._finished_at + _duration(
            self._p["finish_hold"]
        ):
            self.get_logger().info("finished; exiting (exit_on_finish)")
            self.context.try_shutdown()

    def _send(self, k: int) -> None:
        """Request the plan of schedule tick k (point k % n)."""
        x, y = (float(v) for v in self._ref.p_des[k % self._n])
        request = PlanSetpoint.Request(
            x=x, y=y, planner=PLANNER_CODES[self._p["planner"]], warm_start=self._warm_start
        )
        future = self._client.call_async(request)
        self._pending[k] = (future, self.get_clock().now())
        future.add_done_callback(lambda f, k=k: self._on_answer(k, f))

    def _on_answer(self, k: int, future: Future) -> None:
        """Publish a successful plan as the active setpoint, or report the failure and keep the
        previous one."""
        entry = self._pending.pop(k, None)
        if entry is None:
            return  # already reported as timed out
        now = self.get_clock().now()
        self._max_latency = max(self._max_latency, (now - entry[1]).nanoseconds * 1e-9)
        response: PlanSetpoint.Response = future.result()
        j = k % self._n
        if response.success:
            msg = response.setpoint
            msg.trajectory_index, msg.trajectory_length = j, self._n
            # when it becomes the active point: a tick at this instant still uses the last
            msg.header.stamp = now.to_msg()
            self._setpoint_pub.publish(msg)
            self._setpoint_index = j
            self._published += 1
            self.get_logger().debug(f"setpoint {j}/{self._n} published")
        else:
            self._fail(k, _status_name(response.status), response.message)
        self._after_answer(now, k)

    def _after_answer(self, now: Time, k: int) -> None:
        """Record tick k as answered; start the schedule at the first answer (t = 0), finish when
        nothing is pending."""
        self._index = k % self._n
        if self._t0 is None:
            self._t0 = now
            self._tick_timer = self.create_timer(self._slot_s(0), self._tick)
        if self._schedule_done and not self._pending:
            self._finished_at = now
            self._set_state("finished")
            self.get_logger().info(
                f"{self._ref.name} finished: {self._published} setpoints published, "
                f"{self._failures} failed; "
                f"holding setpoint {self._setpoint_index}"
            )
        else:
            self._publish_status()

    def _slot_s(self, k: int) -> float:
        """[s] the length of point k's slot (1/rate, or from 'times'), given so that rclpy's
        create_timer, which truncates to whole ns, gets the slot's ns exactly."""
        if not self._p["times"]:
            return self._period
        ends = [*self._ref.t[1:], self._ref.duration]
        slot_ns = round(ends[k % self._n] * 1e9) - round(self._ref.t[k % self._n] * 1e9)
        return (slot_ns + 0.5) * 1e-9

    def _tick(self) -> None:
        """Next schedule slot: request its point, or end the schedule after the last slot."""
        self._k += 1
        if self._p["times"] and (
            self._k < self._n or self._p["loop"]
        ):  # slots of their own lengths
            self.destroy_timer(self._tick_timer)
            self._tick_timer = self.create_timer(self._slot_s(self._k), self._tick)
        if self._k < self._n or self._p["loop"]:
            self._send(self._k)
            return
        self._tick_timer.cancel()
        self._schedule_done = True
        if not self._pending:
            self._after_answer(self.get_clock().now(), self._k - 1)

    def _fail(self, k: int, status: str, message: str) -> None:
        """Count and report a point that produced no setpoint."""
        j = k % self._n
        x, y = (float(v) for v in self._ref.p_des[j])
        self._failures += 1
        self._last_failure = {"index": j, "x": x, "y": y, "status": status, "message": message}
        held = (
            f"setpoint {self._setpoint_index} stays active"
            if self._setpoint_index >= 0
            else "no setpoint yet"
        )
        self.get_logger().warning(
            f"point {j} ({x:.6g}, {y:.6g}) not planned: {status}: {message}; {held} "
            f"({self._failures} failed so far, on /diagnostics)",
            throttle_duration_sec=5.0,
        )

    def _set_state(self, state: str) -> None:
        """Change the sequencer state and publish it."""
        self._state = state
        self._publish_status()

    def _publish_status(self) -> None:
        """Latched JSON status for run scripts."""
        status = {
            "state": self._state,
            "trajectory": self._ref.name,
            "index": self._index,
            "setpoint_index": self._setpoint_index,
            "length": self._n,
            "finished": self._state == "finished",
            "failures": self._failures,
            "last_failure": self._last_failure,
        }
        self._status_pub.publish(String(data=json.dumps(status)))

    def _report(self) -> Report:
        """Progress, failures and the worst plan latency."""
        values = {
            "state": self._state,
            "index": self._index,
            "length": self._n,
            "published": self._published,
            "failures": self._failures,
            "pending": len(self._pending),
            "max plan latency [s]": f"{self._max_latency:.4f}",
            "last failure": json.dumps(self._last_failure) if self._last_failure else "-",
        }
        if self._state == "waiting_for_service":
            return Report(WARN, f"waiting for service '{self._client.srv_name}'", values)
        level = WARN if self._failures else OK
        return Report(
            level,
            f"{self._state}: point {self._index + 1}/{self._n}, {self._failures} failed",
            values,
        )


def _duration(seconds: float) -> Duration:
    """rclpy Duration of a float number of seconds."""
    return Duration(nanoseconds=int(round(seconds * 1e9)))


def _status_name(status: int) -> str:
    """STATUS_* name of a PlanSetpoint status code."""
    names = {
        getattr(PlanSetpoint.Response, n): n[len("STATUS_") :]
        for n in dir(PlanSetpoint.Response)
        if n.startswith("STATUS_")
    }
    return names.get(status, str(status))


def main() -> None:
    """Console script `setpoint_sequencer`."""
    raise SystemExit(run(SetpointSequencer, "setpoint_sequencer"))

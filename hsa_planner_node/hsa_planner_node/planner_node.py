"""planner_node: the `plan_setpoint` service, desired EE position -> steady-state setpoint
(planning_and_control.md §2).

The planners are hsa_core.task.planning.Planner objects, one per kind in the `planners` parameter,
compiled in the constructor; a request never compiles. Every outcome is a response: failures carry a
status and a reason, so no setpoint is ever dropped silently (reference_ros_graph.md §6, weakness
9); they are counted on /diagnostics and logged at most every 5 s. The service uses
hsa_common.qos.SERVICE (reliable, keep all), so no request of a burst is overwritten before it is
served.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.parameter import Parameter

from hsa_common import convert, qos
from hsa_common.diagnostics import OK, WARN, Diagnostics, Report
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_core.task.planning import (
    DEFAULT_PLANNER,
    MAX_OPTIMALITY_ERROR,
    PLANNER_KINDS,
    Planner,
    PlanResult,
    PlanStatus,
)
from hsa_msgs.msg import Setpoint
from hsa_msgs.srv import PlanSetpoint

FRAME_ID = "hsa_base"
REQUEST_KINDS = {
    PlanSetpoint.Request.PLANNER_STATIC: "static",
    PlanSetpoint.Request.PLANNER_ROLLOUT: "rollout",
}
"""Planner codes of the request other than PLANNER_DEFAULT."""


def _check_planners(value: Any) -> str | None:
    """Unset/empty, or distinct known planner kinds."""
    kinds = list(value or [])
    unknown = [k for k in kinds if k not in PLANNER_KINDS]
    if unknown:
        return f"has unknown planner kind {unknown[0]!r}; expected some of {list(PLANNER_KINDS)}"
    if len(set(kinds)) != len(kinds):
        return f"lists a planner twice: {kinds}"
    return None


SPECS = (
    *MODEL_SPECS,
    ParamSpec(
        "planners",
        Parameter.Type.STRING_ARRAY,
        f"planner kinds compiled at start, some of {list(PLANNER_KINDS)}; the first serves "
        "PLANNER_DEFAULT requests (unset or empty = the material's default planner)",
        read_only=True,
        validator=_check_planners,
    ),
    ParamSpec(
        "max_optimality_error",
        MAX_OPTIMALITY_ERROR,
        "[mixed: N m^2, N m] acceptance threshold on the residual norm of a plan",
        low=1e-15,
        high=MAX_OPTIMALITY_ERROR,
        read_only=True,
    ),
    ParamSpec(
        "max_iterations",
        100,
        "[-] solver iteration limit per plan",
        low=1,
        high=10000,
        read_only=True,
    ),
)


class PlannerNode(Node):
    """Serves `plan_setpoint` from planners compiled at start; counts requests and failures for
    /diagnostics."""

    def __init__(self) -> None:
        """Declare and validate parameters, compile the planners, then offer the service."""
        super().__init__("planner_node")
        values = declare(self, SPECS)
        guard_updates(self, SPECS)
        params = load_model(values)
        kinds = list(values["planners"] or []) or [DEFAULT_PLANNER.get(params.material, "static")]
        self._planners = {
            kind: Planner(
                params,
                kind,
                max_optimality_error=values["max_optimality_error"],
                max_iter=values["max_iterations"],
            )
            for kind in kinds
        }
        self._default_kind = kinds[0]
        self._requests = 0
        self._failures: Counter[str] = Counter()
        self._last_failure = ""
        self._period_failures = 0
        self._solve_times: list[float] = []
        self._max_solve_time = 0.0
        self.create_service(PlanSetpoint, "plan_setpoint", self._serve, qos_profile=qos.SERVICE)
        diagnostics = Diagnostics(self)
        diagnostics.add("planning", self._report)
        self.get_logger().info(
            f"planners {kinds} compiled for material '{params.material}'; default '{kinds[0]}'"
        )

    def _serve(
        self, request: PlanSetpoint.Request, response: PlanSetpoint.Response
    ) -> PlanSetpoint.Response:
        """Answer one request; any failure, including an unexpected exception, becomes success=false
        with a reason."""
        self._requests += 1
        try:
            result = self._plan(request)
        except (
            Exception
        ) as exc:  # the service must answer; the reason goes to the caller and the log
            self.get_logger().error(f"planner raised for ({request.x}, {request.y}): {exc!r}")
            result = PlanResult(
                False,
                PlanStatus.NOT_CONVERGED,
                f"planner error: {exc!r}",
                None,
                math.nan,
                0,
                0.0,
                "",
            )
        response.success = result.success
        response.status = int(result.status)
        response.message = result.message
        response.planner_used = result.planner
        response.iterations = int(result.iterations)
        response.solve_time = float(result.solve_time_s)
        self._solve_times.append(response.solve_time)
        self._max_solve_time = max(self._max_solve_time, response.solve_time)
        if result.setpoint is not None:
            response.setpoint = self._setpoint_msg(result)
        else:
            self._failures[result.status.name] += 1
            self._period_failures += 1
            self._last_failure = result.message
            self.get_logger().warning(
                f"plan for ({request.x:.6g}, {request.y:.6g}) refused: {result.status.name}: "
                f"{result.message} "
                f"({sum(self._failures.values())} refused so far, on /diagnostics)",
                throttle_duration_sec=5.0,
            )
        return response

    def _plan(self, request: PlanSetpoint.Request) -> PlanResult:
        """Select the planner named by the request and plan; malformed requests are refused before
        solving."""
        if request.planner == PlanSetpoint.Request.PLANNER_DEFAULT:
            kind = self._default_kind
        elif request.planner in REQUEST_KINDS:
            kind = REQUEST_KINDS[request.planner]
        else:
            return _invalid(
                f"unknown planner code {request.planner}; expected one of "
                "PLANNER_DEFAULT/STATIC/ROLLOUT"
            )
        if kind not in self._planners:
            return _invalid(
                f"planner '{kind}' is not compiled in this node (parameter 'planners': "
                f"{list(self._planners)})",
                kind,
            )
        if not (math.isfinite(request.x) and math.isfinite(request.y)):
            return _invalid(f"x and y must be finite, got ({request.x}, {request.y})", kind)
        return self._planners[kind].plan(
            np.array([request.x, request.y]), warm_start=request.warm_start
        )

    def _setpoint_msg(self, result: PlanResult) -> Setpoint:
        """The Setpoint message of a successful plan, stamped now in the base frame."""
        sp = result.setpoint
        msg = Setpoint()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = FRAME_ID
        msg.chiee_des = convert.planar_pose_msg(sp.chiee_des)
        msg.q_des = convert.configuration_msg(sp.q_des)
        msg.phi_ss = np.asarray(sp.phi_ss, dtype=np.float64)
        msg.optimality_error = float(sp.optimality_error)
        return msg

    def _report(self) -> Report:
        """Requests and failures (cumulative; WARN if any failed this period), solve-time
        statistics."""
        times, self._solve_times = self._solve_times, []
        period_failures, self._period_failures = self._period_failures, 0
        failed = sum(self._failures.values())
        values: dict[str, object] = {
            "requests": self._requests,
            "failures": failed,
            **{f"failures {k}": n for k, n in self._failures.items()},
            "solve time mean [s] (period)": f"{np.mean(times):.6f}" if times else "-",
            "solve time max [s]": f"{self._max_solve_time:.6f}",
            "last failure": self._last_failure or "-",
            "planners": ", ".join(self._planners),
        }
        message = f"{failed} of {self._requests} requests failed"
        level = WARN if period_failures else OK
        return Report(level, message, values)


def _invalid(reason: str, kind: str = "") -> PlanResult:
    """A refused request (nothing was solved)."""
    return PlanResult(False, PlanStatus.INVALID_REQUEST, reason, None, math.nan, 0, 0.0, kind)


def main() -> None:
    """Console script `planner_node`."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(PlannerNode, "planner_node"))

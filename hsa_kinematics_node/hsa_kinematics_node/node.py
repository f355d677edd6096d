"""kinematics_node: per ``ee_pose`` sample, q by closed-form IK and causal Savitzky–Golay rates →
``state``.

One ``state`` (hsa_msgs/PlanarState) per accepted ``ee_pose`` sample, with the mocap stamp (spec
§6.3–6.4). q̇ and χ̇_ee are the end-point derivative of a polynomial fit over the last ``window``
samples of [q, χ_ee]; until the window is full (after start-up or a stamp gap) ``velocity_valid`` is
false and both rates are NaN, never a made-up zero. Samples the estimator rejects (non-finite,
duplicate or out-of-order stamps) produce no ``state`` and are counted on /diagnostics. So are
samples whose state would go out more than ``max_lag`` later, relative to their stamp, than the
promptest of the last second (hsa_core.controller.validation.DelayGate: samples queued, or in
flight, while this node was stalled, which would otherwise come out as an old state with a valid
velocity); they still enter the window. The gate judges before ``publish()``: a node stopped inside
the write still delivers that state late, so consumers judge age by stamp. Parameters and topics:
docs/nodes/hsa_kinematics_node.md.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.time import Time

from hsa_common import convert, qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report, log_level_change
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare, guard_updates
from hsa_common.runner import run, seconds
from hsa_core.controller.validation import DelayGate
from hsa_core.jaxsetup import configure_jax
from hsa_core.rate_meter import RateMeter
from hsa_core.sensing.estimation import (
    EstimateMode,
    SavitzkyGolayDifferentiator,
    configuration_from_pose,
)
from hsa_core.sensing.mocap import REST_POSE
from hsa_msgs.msg import PlanarPoseStamped, PlanarState

NOT_AVAILABLE = (math.nan,) * 6  # rates [q̇, χ̇_ee] while the estimator is not ready


SPECS = (
    *MODEL_SPECS,
    ParamSpec(
        "window",
        20,
        "[samples] Savitzky-Golay window N (at least order + 2)",
        low=3,
        high=200,
        read_only=True,
    ),
    ParamSpec(
        "order", 3, "[-] degree of the Savitzky-Golay polynomial", low=1, high=6, read_only=True
    ),
    ParamSpec(
        "mocap_rate",
        200.0,
        "[Hz] nominal ee_pose rate; the estimator period is T = 1/mocap_rate",
        low=1.0,
        high=2000.0,
        read_only=True,
    ),
    ParamSpec(
        "gap_factor",
        5.0,
        "[-] a stamp interval longer than gap_factor * T restarts the window (shorter gaps "
        "are bridged by a fit on the true stamps)",
        low=1.01,
        high=100.0,
    ),
    ParamSpec(
        "regular_tol",
        1e-3,
        "[-] stamp jitter, relative to T, up to which the precomputed coefficients are "
        "used (else a fit on the true stamps)",
        low=0.0,
        high=0.5,
    ),
    ParamSpec(
        "max_lag",
        0.1,
        "[s] publish no state whose sample is this much later, relative to its stamp, than the "
        "promptest of the last second of samples (queued or in flight during a stall); 0 = off",
        low=0.0,
        high=10.0,
        read_only=True,
    ),
    ParamSpec(
        "stale_timeout",
        0.25,
        "[s] diagnostics ERROR when no ee_pose arrived for this long",
        low=0.001,
        high=60.0,
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


class KinematicsNode(Node):
    """Turns each ``ee_pose`` into a ``state``: q by IK, rates of q and χ_ee by Savitzky–Golay
    differentiation."""

    def __init__(self) -> None:
        super().__init__("kinematics_node")
        self._p = declare(self, SPECS)
        self._params = load_model(self._p)
        self._estimator = self._make_estimator()
        self._delay = DelayGate(self._p["max_lag"], history=max(1, round(self._p["mocap_rate"])))
        # JIT-compile the IK now, not on the first sample
        configuration_from_pose(self._params, REST_POSE)
        guard_updates(self, SPECS, self._update)
        self._received = self._published = self._restarts = 0
        self._rejected: Counter[str] = Counter()
        # first stamp; estimator times are seconds since it (float precision)
        self._origin_ns: int | None = None
        self._last_stamp_ns: int | None = None
        self._last_received_at: Time | None = None
        self._mode = "no data"
        self._level: bytes | None = None  # diagnostics level last reported
        self._rates = RateMeter(self.get_clock().now().nanoseconds)
        self._pub = self.create_publisher(
            PlanarState, "state", qos.SENSOR, qos_overriding_options=qos.overridable()
        )
        self.create_subscription(
            PlanarPoseStamped,
            "ee_pose",
            self._on_pose,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        self._diagnostics = Diagnostics(self, self._p["diagnostics_period"])
        self._diagnostics.add("estimator", self._report)

    def _make_estimator(self) -> SavitzkyGolayDifferentiator:
        """A fresh differentiator of [q, χ_ee] (dim 6) from the current parameters (raises naming
        the parameter)."""
        p = self._p
        try:
            return SavitzkyGolayDifferentiator(
                window=p["window"],
                order=p["order"],
                dim=6,
                nominal_period=1.0 / p["mocap_rate"],
                regular_tol=p["regular_tol"],
                gap_factor=p["gap_factor"],
            )
        except ValueError as exc:
            raise ParameterValidationError(f"parameter 'window': {exc}") from exc

    def _update(self, changes: dict[str, Any]) -> None:
        """Apply accepted run-time updates; estimator settings restart the window."""
        self._p.update(changes)
        if {"gap_factor", "regular_tol"} & changes.keys():
            self._estimator = self._make_estimator()
            self.get_logger().info(
                f"estimator settings changed ({sorted(changes)}): window restarted"
            )

    def _on_pose(self, msg: PlanarPoseStamped) -> None:
        """IK and rate estimate for one pose sample; publish the state unless the estimator rejects
        the sample."""
        self._received += 1
        self._last_received_at = self.get_clock().now()
        stamp_ns = convert.stamp_ns(msg.header.stamp)
        if self._origin_ns is None:
            self._origin_ns = stamp_ns
        chiee = convert.planar_pose(msg.pose)
        q = configuration_from_pose(self._params, chiee)
        estimate = self._estimator.update(
            (stamp_ns - self._origin_ns) * 1e-9, np.concatenate([q, chiee])
        )
        self._mode = estimate.mode
        if estimate.mode is EstimateMode.REJECTED:
            self._rejected[estimate.rejection] += 1
            self.get_logger().warning(
                f"dropped ee_pose sample: {estimate.reason}", throttle_duration_sec=5.0
            )
            return
        if estimate.reason:  # a stamp gap restarted the window
            self._restarts += 1
            self.get_logger().warning(estimate.reason, throttle_duration_sec=5.0)
        if self._delay.late(
            stamp_ns, self.get_clock().now().nanoseconds
        ):  # judged when it would go out
            self._rejected["delayed sample"] += 1
            self.get_logger().warning(
                f"dropped ee_pose sample: its state would go out > {self._p['max_lag']:g} s "
                "late (queued or in flight while this node stalled)",
                throttle_duration_sec=5.0,
            )
            return
        self._last_stamp_ns = stamp_ns
        rates = estimate.derivative if estimate.derivative is not None else NOT_AVAILABLE
        out = PlanarState()
        out.header = msg.header
        out.chiee = msg.pose
        out.chiee_dot = convert.planar_pose_msg(rates[3:])
        out.q = convert.configuration_msg(estimate.value)
        out.q_dot = convert.configuration_msg(rates)
        out.velocity_valid = estimate.ready
        out.window_samples = self._estimator.n_samples
        self._pub.publish(out)
        self._published += 1

    def _report(self) -> Report:
        """Input silence level, estimator mode and window fill, counts of rejected samples and
        window restarts."""
        now = self.get_clock().now()
        counts = {"received": self._received, "published": self._published}
        rates = self._rates.rates(now.nanoseconds, counts)
        values: dict[str, object] = {
            **counts,
            "rejected": sum(self._rejected.values()),
            **{f"rejected: {reason}": n for reason, n in sorted(self._rejected.items())},
            "window_restarts": self._restarts,
            "mode": self._mode,
            "window_samples": f"{self._estimator.n_samples}/{self._estimator.window}",
            "input_rate_hz": round(rates["received"], 1),
            "output_rate_hz": round(rates["published"], 1),
            "material": self._params.material,
            "sigma_a_eq": np.asarray(self._params.sigma_a_eq).tolist(),
        }
        if self._last_stamp_ns is not None:
            values["last_sample_age_s"] = round((now.nanoseconds - self._last_stamp_ns) * 1e-9, 4)
        if self._last_received_at is None:
            level, message = WARN, "waiting for ee_pose"
        elif (silence := seconds(now - self._last_received_at)) > self._p["stale_timeout"]:
            level, message = ERROR, f"stale: no ee_pose for {silence:.3g} s"
        elif self._estimator.n_samples < self._estimator.window:
            level, message = WARN, f"velocity not ready (window {values['window_samples']})"
        else:
            level, message = OK, f"estimating ({self._mode})"
        self._level = log_level_change(self.get_logger(), self._level, level, message)
        return Report(level, message, values)


def main() -> None:
    """Console script ``kinematics_node``."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(KinematicsNode, "kinematics_node"))

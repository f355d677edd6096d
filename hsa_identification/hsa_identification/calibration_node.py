"""calibration_node: the `calibrate_rest_strain` service (hsa_msgs/srv/CalibrateRestStrain) from the
live state stream.

It keeps the newest `state` samples (EE pose, mocap stamp, receive time) and `phi_present` samples
(the driver's present twist, receive time; receive times pair the two streams, so an unsynchronised
mocap clock does no harm). A request takes the last `num_samples` states, refuses unless the robot
is at rest with phi = 0 over that window (hsa_core.sysid.calibration.rest_problem: phi, pose spread
and drift), and otherwise returns sigma_a_eq of both virtual rods with its one-sigma uncertainty and
residual (hsa_core.sysid.calibration.calibrate, planning_and_control.md §6.5). With
`write_parameter_file` it writes the estimate into the parameter file in use (`write_file`, else
`params_file`; the packaged set is never overwritten), keeping every other line. Nodes read
sigma_a_eq at start: restart them (or pass the values as their `sigma_a_eq` parameter) to use a new
calibration.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node

from hsa_common import convert, qos
from hsa_common.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParamSpec, declare, guard_updates
from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.params import CONFIG_DIR
from hsa_core.sysid import calibration
from hsa_core.sysid.identification import write_parameter_file
from hsa_msgs.msg import PlanarActuation, PlanarState
from hsa_msgs.srv import CalibrateRestStrain

SPECS = (
    *MODEL_SPECS,
    ParamSpec(
        "num_samples",
        200,
        "[-] state samples per calibration when the request asks for 0 (1 s at 200 Hz)",
        low=calibration.MIN_SAMPLES,
        high=20000,
        read_only=True,
    ),
    ParamSpec(
        "buffer_size",
        2000,
        "[-] newest state samples kept (largest num_samples a request may ask for)",
        low=calibration.MIN_SAMPLES,
        high=20000,
        read_only=True,
    ),
    ParamSpec(
        "phi_tol",
        calibration.PHI_TOL,
        "[rad] largest |phi| that counts as untwisted",
        low=0.0,
        high=0.5,
    ),
    ParamSpec(
        "max_spread",
        calibration.MAX_POSITION_SPREAD,
        "[m] largest peak-to-peak EE position in the window at rest",
        low=0.0,
        high=0.1,
    ),
    ParamSpec(
        "max_angle_spread",
        calibration.MAX_ANGLE_SPREAD,
        "[rad] largest peak-to-peak EE angle in the window at rest",
        low=0.0,
        high=1.0,
    ),
    ParamSpec(
        "max_speed",
        calibration.MAX_SPEED,
        "[m/s] largest EE drift speed (fitted slope) at rest",
        low=0.0,
        high=1.0,
    ),
    ParamSpec(
        "phi_timeout",
        0.5,
        "[s] phi_present received more than this before the window's first state does not count",
        low=0.01,
        high=60.0,
    ),
    ParamSpec(
        "write_file",
        "",
        "parameter YAML to write on request (empty = params_file; the packaged set is "
        "never overwritten)",
        read_only=True,
    ),
)


class CalibrationNode(Node):
    """Buffers state and phi_present; serves calibrate_rest_strain; reports the last result in
    /diagnostics."""

    def __init__(self) -> None:
        """Declare parameters, load the model, compile the calibration for the default window, offer
        the service."""
        super().__init__("calibration_node")
        self._values = declare(self, SPECS)
        guard_updates(self, SPECS, self._values.update)
        self._params = load_model(self._values)
        self._states: deque[tuple[float, float, np.ndarray]] = deque(
            maxlen=self._values["buffer_size"]
        )
        self._phis: deque[tuple[float, np.ndarray]] = deque(maxlen=self._values["buffer_size"])
        n = self._values["num_samples"]
        # compile now
        calibration.calibrate(self._params, np.tile([0.0, float(self._params.l), 0.0], (n, 1)))
        self._last: dict[str, Any] = {"result": "none yet"}
        self._level = WARN
        self.create_subscription(
            PlanarState,
            "state",
            self._on_state,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        self.create_subscription(
            PlanarActuation,
            "phi_present",
            self._on_phi,
            qos.SENSOR,
            qos_overriding_options=qos.overridable(),
        )
        self.create_service(CalibrateRestStrain, "calibrate_rest_strain", self._serve)
        diagnostics = Diagnostics(self)
        diagnostics.add("calibration", self._report)

    def _now(self) -> float:
        """Node clock [s]."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_state(self, msg: PlanarState) -> None:
        """Keep the sample (mocap stamp, receive time, EE pose)."""
        self._states.append(
            (convert.stamp_s(msg.header.stamp), self._now(), convert.planar_pose(msg.chiee))
        )

    def _on_phi(self, msg: PlanarActuation) -> None:
        """Keep the present twist with its receive time."""
        self._phis.append((self._now(), convert.actuation(msg)))

    def _serve(
        self, request: CalibrateRestStrain.Request, response: CalibrateRestStrain.Response
    ) -> CalibrateRestStrain.Response:
        """Check the rest, estimate, optionally write the file; every refusal is success=false with
        the reason."""
        n = int(request.num_samples) or self._values["num_samples"]
        states = list(self._states)[-n:]
        if len(states) < n:
            return self._refuse(
                response, f"not enough samples: {len(states)} of {n} state samples buffered"
            )
        t = np.array([s[0] for s in states])
        chiee = np.array([s[2] for s in states])
        since = states[0][1] - self._values["phi_timeout"]
        phi = np.array([p for received, p in self._phis if received >= since]).reshape(-1, 2)
        problem = calibration.rest_problem(
            t,
            chiee,
            phi,
            phi_tol=self._values["phi_tol"],
            max_spread=self._values["max_spread"],
            max_angle_spread=self._values["max_angle_spread"],
            max_speed=self._values["max_speed"],
        )
        if problem is not None:
            return self._refuse(response, f"not at rest: {problem}")
        result = calibration.calibrate(self._params, chiee)
        response.sigma_a_eq = result.sigma_a_eq.astype(float)
        response.sigma_a_eq_std = result.sigma_a_eq_std.astype(float)
        response.residual_rms = float(result.residual_rms)
        response.samples_used = result.samples_used
        response.success, response.message = True, "ok"
        if request.write_parameter_file:
            target = self._values["write_file"] or self._values["params_file"]
            if not target:
                response.success = False
                response.message = (
                    "estimated, but no file written: set 'params_file' or 'write_file'"
                )
            else:
                base = Path(
                    self._values["params_file"] or CONFIG_DIR / f"{self._values['material']}.yaml"
                )
                header = (
                    f"sigma_a_eq calibrated by calibration_node: {result.sigma_a_eq.tolist()} "
                    f"+- {result.sigma_a_eq_std.tolist()} ({result.samples_used} samples)"
                )
                path = write_parameter_file(
                    base,
                    Path(target),
                    {"sigma_a_eq": result.sigma_a_eq.tolist()},
                    header=header if base != Path(target) else "",
                )
                response.parameter_file = str(path)
        estimate = ", ".join(f"{v:.6f}" for v in result.sigma_a_eq)
        self.get_logger().info(
            f"sigma_a_eq = [{estimate}] +- {np.max(result.sigma_a_eq_std):.2g} from {n} samples"
            + (f", written to {response.parameter_file}" if response.parameter_file else "")
        )
        self._last = {
            "result": f"[{estimate}]",
            "std": f"{result.sigma_a_eq_std.tolist()}",
            "residual_rms": f"{result.residual_rms:.3g}",
            "file": response.parameter_file or "-",
        }
        self._level = OK if response.success else ERROR
        return response

    def _refuse(
        self, response: CalibrateRestStrain.Response, reason: str
    ) -> CalibrateRestStrain.Response:
        """A refused request: the reason to the caller and the log (once per request)."""
        response.success, response.message = False, reason
        self.get_logger().warning(f"calibration refused: {reason}")
        self._last = {**self._last, "last refusal": reason}
        return response

    def _report(self) -> Report:
        """Buffered samples and the last result or refusal."""
        values = {
            "states buffered": len(self._states),
            "phi samples buffered": len(self._phis),
            **self._last,
        }
        if not self._states:
            return Report(WARN, "waiting for state", values)
        return Report(self._level if self._level != WARN else OK, "ready", values)


def main() -> None:
    """Console script `calibration_node`."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(CalibrationNode, "calibration_node"))

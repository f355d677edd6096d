"""excitation_player: plays a step, staircase or GBN twist sequence (hsa_core.sysid.excitation) on
`phi_cmd`.

The commands take the normal actuation path: the controller's topic and QoS
(hsa_msgs/PlanarActuation, COMMAND), so the dynamixel_driver applies its clip, goal clamp, rate
limit and watchdog exactly as in closed loop (do not run a controller at the same time). One command
per period `dt` (25 Hz by default, faster than the driver's 0.1 s command watchdog). Before the
sequence and after it the player sends phi = 0 (`start_delay`, `final_hold`), so records start and
end untwisted (identification.md §2.1). Everything that defines the sequence (kind, mode, seed,
levels) is published once on the latched `excitation_info` (std_msgs/String, JSON) so a bag recorded
alongside holds it (§2.4 item 4). With `exit_on_finish` the process exits 0 after the final hold.
"""

from __future__ import annotations

import json

import numpy as np
from rclpy.node import Node
from std_msgs.msg import String

from hsa_common import convert, qos
from hsa_common.model_params import MODEL_SPECS, load_model
from hsa_common.parameters import ParameterValidationError, ParamSpec, declare
from hsa_common.runner import run
from hsa_core.jaxsetup import configure_jax
from hsa_core.sysid import excitation
from hsa_msgs.msg import PlanarActuation

SPECS = (
    *MODEL_SPECS,
    ParamSpec("kind", "gbn", "excitation family", choices=excitation.KINDS, read_only=True),
    ParamSpec(
        "mode",
        "combined",
        "rods driven: elongation (both equal), rod1, rod2, combined (GBN only)",
        choices=excitation.MODES,
        read_only=True,
    ),
    ParamSpec(
        "phi_max",
        0.0,
        "[rad] largest twist of the sequence; 0 = the smaller phi_max of the parameter set",
        low=0.0,
        high=2.0 * np.pi,
        read_only=True,
    ),
    ParamSpec(
        "level", 0.0, "[rad] step level; 0 = phi_max", low=0.0, high=2.0 * np.pi, read_only=True
    ),
    ParamSpec(
        "duration",
        50.0,
        "[s] length of a step or GBN sequence",
        low=0.1,
        high=3600.0,
        read_only=True,
    ),
    ParamSpec(
        "t_step",
        1.0,
        "[s] time of the step within the sequence",
        low=0.0,
        high=3600.0,
        read_only=True,
    ),
    ParamSpec("n_levels", 5, "[-] staircase increments above 0", low=1, high=100, read_only=True),
    ParamSpec("hold", 5.8, "[s] staircase hold per level", low=0.1, high=3600.0, read_only=True),
    ParamSpec(
        "settling_time",
        excitation.DEFAULT_SETTLING_TIME,
        "[s] GBN settling-time parameter (mean hold)",
        low=0.01,
        high=100.0,
        read_only=True,
    ),
    ParamSpec("seed", 0, "[-] GBN seed", low=0, high=2**31 - 1, read_only=True),
    ParamSpec(
        "dt", excitation.DEFAULT_DT, "[s] command period", low=0.005, high=0.09, read_only=True
    ),
    ParamSpec(
        "start_delay",
        2.0,
        "[s] phi = 0 before the sequence (subscribers connect, the robot settles)",
        low=0.0,
        high=600.0,
        read_only=True,
    ),
    ParamSpec(
        "final_hold", 2.0, "[s] phi = 0 after the sequence", low=0.0, high=600.0, read_only=True
    ),
    ParamSpec("exit_on_finish", True, "exit (code 0) after the final hold", read_only=True),
)


class ExcitationPlayer(Node):
    """Publishes the excitation on phi_cmd at its command period, zero before and after."""

    def __init__(self) -> None:
        """Build the sequence from the parameters (ValueError names a bad combination), publish its
        description."""
        super().__init__("excitation_player")
        v = declare(self, SPECS)
        params = load_model(v)
        phi_max = v["phi_max"] or float(np.min(np.asarray(params.phi_max)))
        try:
            self._exc = excitation.make(
                v["kind"],
                phi_max,
                duration=v["duration"],
                mode=v["mode"],
                seed=v["seed"],
                level=v["level"] or None,
                n_levels=v["n_levels"],
                hold=v["hold"],
                t_step=v["t_step"],
                settling_time=v["settling_time"],
                dt=v["dt"],
            )
        except ValueError as exc:
            raise ParameterValidationError(f"parameter 'kind'/'mode': {exc}") from exc
        self._phi_limit = phi_max
        self._start_delay, self._final_hold, self._exit = (
            v["start_delay"],
            v["final_hold"],
            v["exit_on_finish"],
        )
        self._pub = self.create_publisher(
            PlanarActuation, "phi_cmd", qos.COMMAND, qos_overriding_options=qos.overridable()
        )
        info = self.create_publisher(String, "excitation_info", qos.LATCHED)
        description = {
            "kind": self._exc.kind,
            "mode": self._exc.mode,
            "seed": self._exc.seed,
            "phi_max": phi_max,
            "dt": self._exc.dt,
            "samples": len(self._exc.t),
            "duration": self._exc.duration,
            "start_delay": self._start_delay,
            "final_hold": self._final_hold,
            **{key: v[key] for key in ("level", "n_levels", "hold", "t_step", "settling_time")},
        }
        info.publish(String(data=json.dumps(description)))
        # node clock: simulated time under use_sim_time (lockstep)
        self._t0 = self.get_clock().now()
        self._finished = False
        self.create_timer(self._exc.dt, self._tick)
        self.get_logger().info(
            f"playing {self._exc.kind} ({self._exc.mode}, seed {self._exc.seed}) for "
            f"{self._exc.duration:.1f} s after {self._start_delay:.1f} s"
        )

    def _tick(self) -> None:
        """Publish the command due now; log the end once and exit after the final hold if asked."""
        elapsed = (self.get_clock().now() - self._t0).nanoseconds * 1e-9 - self._start_delay
        phi = (
            np.clip(self._exc.at(elapsed), 0.0, self._phi_limit)
            if elapsed < self._exc.duration
            else np.zeros(2)
        )
        self._pub.publish(convert.actuation_msg(phi, self.get_clock().now().to_msg()))
        if elapsed >= self._exc.duration and not self._finished:
            self._finished = True
            self.get_logger().info("sequence finished; holding phi = 0")
        if elapsed >= self._exc.duration + self._final_hold and self._exit:
            self.get_logger().info("finished; exiting (exit_on_finish)")
            self.context.try_shutdown()


def main() -> None:
    """Console script `excitation_player`."""
    configure_jax()  # the node loads the model: float64 before anything is computed
    raise SystemExit(run(ExcitationPlayer, "excitation_player"))

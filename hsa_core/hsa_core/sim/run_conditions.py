"""A run's conditions where the offline experiment and the ROS graph must apply them the same way
(no ROS).

* :class:`TickEstimator`: the September 2023 velocity estimator (``smoothing_spline_16``,
  hsa_core.runs.profiles), which runs at the controller's ticks: at every tick the newest state
  (stamp, q, χ_ee) enters a cubic end-point fit over the last ``SPLINE_WINDOW`` such samples on
  their true stamps; no estimate (no command) before the 16th. The offline experiment and
  controller_node (parameter ``velocity_estimator``) both run this class.
* :func:`plant_params`: the plant of a run with a payload (it hangs at rest with it from t = 0); the
  controller's model keeps the material's. The offline experiment and sim_node (parameter
  ``payload``) both build their world from it.
* :func:`graph_arguments`: the launch arguments of ``launch_scripts/sim.launch.yaml`` that set a
  profile's or a real run's conditions (control rate, integrators' step, estimator, command latency,
  σ_a,eq, payload; a real run's law and material too), and :func:`run_schedule`: a real run's
  setpoints at its real step instants, as the sequencer's ``points``, ``times`` and ``rate``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hsa_core.model.params import HsaParams
from hsa_core.runs.profiles import RunProfile
from hsa_core.runs.reference import ReferenceRun
from hsa_core.sensing.estimation import SavitzkyGolayDifferentiator
from hsa_core.sim.disturbance import DisturbanceModel

SPLINE_WINDOW, SPLINE_ORDER, SPLINE_GAP_FACTOR = 16, 3, 5.0
"""Samples, degree and gap factor (× the control period) of the September 2023 stand-in
(hsa_core.runs.profiles)."""


class TickEstimator:
    """The September 2023 stand-in estimator, fed once per controller tick (module docstring)."""

    def __init__(self, period: float) -> None:
        """``period`` [s]: the control period (the nominal spacing of the samples)."""
        self._fit = SavitzkyGolayDifferentiator(
            window=SPLINE_WINDOW,
            order=SPLINE_ORDER,
            dim=6,
            gap_factor=SPLINE_GAP_FACTOR,
            nominal_period=period,
        )
        self._origin: int | None = None

    def update(
        self, stamp_ns: int, q: np.ndarray, chiee: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The newest state at a tick → (q̇, χ̇_ee), or None: fewer than SPLINE_WINDOW samples, or
        the same stamp as at the previous tick (no new sample)."""
        self._origin = stamp_ns if self._origin is None else self._origin
        estimate = self._fit.update((stamp_ns - self._origin) * 1e-9, np.concatenate([q, chiee]))
        return (estimate.derivative[:3], estimate.derivative[3:]) if estimate.ready else None


def plant_params(model: HsaParams, payload: float) -> HsaParams:
    """The plant's parameters: ``model`` carrying the point payload ``payload`` [kg] (0: the model
    as it is)."""
    return model.replace(m_pl=payload) if payload else model


def run_disturbance(disturbance: DisturbanceModel, command_latency: float) -> DisturbanceModel:
    """The world of a run: ``disturbance`` with the controller side's ``command_latency`` [s]
    (tick → goal written on the bus) added to its actuation latency."""
    if not (command_latency >= 0.0):
        raise ValueError(f"command_latency must be >= 0 s, got {command_latency}")
    if not command_latency:
        return disturbance
    return dataclasses.replace(
        disturbance, actuation_latency=disturbance.actuation_latency + command_latency
    )


def graph_arguments(
    profile: RunProfile,
    *,
    sigma_a_eq: tuple[float, float] | None = None,
    payload: float | None = None,
    run: ReferenceRun | None = None,
) -> dict[str, str]:
    """Launch arguments of sim.launch.yaml for ``profile`` (a real ``run``: its profile, material,
    law, σ_a,eq and payload); ``sigma_a_eq`` / ``payload`` override the profile's or the run's. The
    run's gains and setpoints are files (gains_file, sequencer_file), written by the caller."""
    if run is not None:
        cond = run.conditions
        profile = cond.profile
        sigma_a_eq = sigma_a_eq if sigma_a_eq is not None else cond.sigma_a_eq
        payload = payload if payload is not None else cond.payload
    sigma = sigma_a_eq if sigma_a_eq is not None else profile.sigma_a_eq
    args = {
        "rate": repr(profile.rate),
        "integrator_dt": repr(profile.integrator_dt or 0.0),
        "velocity_estimator": profile.velocity_estimator.value,
        "payload": repr(float(payload if payload is not None else profile.payload)),
        "command_latency": repr(profile.command_latency_ms * 1e-3),
        "sigma_a_eq": "[]" if sigma is None else f"[{float(sigma[0])!r}, {float(sigma[1])!r}]",
    }
    if run is not None:
        args |= {"material": run.conditions.material, "controller": run.conditions.law.value}
    return args


def run_schedule(run: ReferenceRun) -> dict[str, object]:
    """A real run's setpoints as setpoint_sequencer parameters: ``points`` [m] (flat x, y),
    ``times`` [s] (point k's instant after point 0: the real step instants) and ``rate`` [Hz] (the
    last point lasts 1/rate, to the end of the real run), as :meth:`ReferenceRun.timed_reference`
    gives them to the offline experiment."""
    reference = run.timed_reference()
    times = [float(t) for t in reference.t]
    return {
        "trajectory": "steps",
        "points": [float(v) for v in np.asarray(reference.p_des).ravel()],
        "times": times,
        "rate": 1.0 / (reference.duration - times[-1]),
    }

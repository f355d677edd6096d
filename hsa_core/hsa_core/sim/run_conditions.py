"""A run's conditions where the offline experiment and the ROS graph must apply them the same way
(no ROS).

* :class:`TickEstimator`: the September 2023 velocity estimator (``smoothing_spline_16``,
  hsa_core.runs.profiles), which runs at the controller's ticks: at every tick the newest state
  (stamp, q, χ_ee) enters a cubic end-point fit over the last ``SPLINE_WINDOW`` such samples on
  their true stamps; no estimate (no command) before the 16th. The offline experiment and
  controller_node (parameter ``velocity_estimator``) both run this class; it is :func:`tick_take`
  and :func:`tick_rates` (numpy or jax.numpy), which the batched loop (hsa_core.sim.closed_loop)
  traces.
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
import math
from typing import Any, NamedTuple

import numpy as np

from hsa_core.model.params import HsaParams
from hsa_core.runs.catalogue import CataloguedRun, Replayable
from hsa_core.runs.profiles import RunProfile
from hsa_core.sensing.estimation import derivative_coefficients
from hsa_core.sim.disturbance import DisturbanceModel
from hsa_core.task.trajectories import CONTOUR_RATE

SPLINE_WINDOW, SPLINE_ORDER, SPLINE_GAP_FACTOR = 16, 3, 5.0
"""Samples, degree and gap factor (× the control period) of the September 2023 stand-in
(hsa_core.runs.profiles)."""


class TickWindow(NamedTuple):
    """The September estimator's window (arrays of numpy or jax.numpy): the last ``SPLINE_WINDOW``
    states [q, χ_ee] taken, oldest first; their stamps [s]; the states taken since the last
    (re)start."""

    z: Any
    stamps: Any
    count: Any


def tick_window(xp: Any = np) -> TickWindow:
    """An empty window (no state taken; stamps −inf)."""
    return TickWindow(xp.zeros((SPLINE_WINDOW, 6)), xp.full(SPLINE_WINDOW, -xp.inf), xp.asarray(0))


def tick_take(
    window: TickWindow, stamp: Any, z: Any, period: float, xp: Any = np
) -> tuple[TickWindow, Any]:
    """The newest state (``stamp`` [s], ``z`` = [q, χ_ee]) at a tick → (window, taken). It is taken
    when finite and newer than the window's newest; a gap of more than ``SPLINE_GAP_FACTOR`` control
    periods (``period`` [s]) restarts the count. Traceable with ``xp`` = jax.numpy."""
    newest = window.stamps[-1]
    taken = (stamp > newest) & xp.isfinite(stamp) & xp.all(xp.isfinite(z))
    gap = (window.count > 0) & (stamp - newest > SPLINE_GAP_FACTOR * period)
    shifted = TickWindow(
        xp.concatenate([window.z[1:], xp.reshape(z, (1, 6))]),
        xp.concatenate([window.stamps[1:], xp.reshape(stamp, (1,))]),
        xp.where(gap, 1, window.count + 1),
    )
    return TickWindow(*(xp.where(taken, new, old) for new, old in zip(shifted, window))), taken


def tick_rates(window: TickWindow, xp: Any = np) -> tuple[Any, Any]:
    """(ż (6,), ready): the derivative at the newest stamp of the least-squares cubic through the
    window on its true stamps, and whether ``SPLINE_WINDOW`` states were taken since the last
    (re)start (a window not ready gives a finite derivative that means nothing)."""
    ready = window.count >= SPLINE_WINDOW
    stamps = xp.where(ready, window.stamps, xp.arange(SPLINE_WINDOW) * 1.0)
    mean_dt = (stamps[-1] - stamps[0]) / (SPLINE_WINDOW - 1)
    c = derivative_coefficients((stamps - stamps[-1]) / mean_dt, SPLINE_ORDER, xp)
    return c @ window.z / mean_dt, ready


class TickEstimator:
    """The September 2023 stand-in estimator, fed once per controller tick (module docstring):
    :func:`tick_take` and :func:`tick_rates` in numpy, as the batched loop runs them in
    jax.numpy."""

    def __init__(self, period: float) -> None:
        """``period`` [s]: the control period (the nominal spacing of the samples)."""
        self._period = period
        self._window = tick_window()
        self._origin: int | None = None

    def update(
        self, stamp_ns: int, q: np.ndarray, chiee: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The newest state at a tick → (q̇, χ̇_ee), or None: fewer than SPLINE_WINDOW samples since
        the last (re)start, or a state not taken (the same stamp as at the previous tick, older, or
        not finite)."""
        self._origin = stamp_ns if self._origin is None else self._origin
        self._window, taken = tick_take(
            self._window, (stamp_ns - self._origin) * 1e-9, np.concatenate([q, chiee]), self._period
        )
        rates, ready = tick_rates(self._window)
        return (rates[:3], rates[3:]) if taken and ready else None


PAYLOAD_COG = (0.0, -0.0255)
"""[m] the CoG of the paper's payloads (0.2 and 0.4 kg) in the EE frame (spec model.md §2)."""


def plant_params(model: HsaParams, payload: float) -> HsaParams:
    """The plant's parameters: ``model`` carrying a run's point payload ``payload`` [kg] at the
    paper's payload CoG :data:`PAYLOAD_COG` (0: the model as it is)."""
    return model.replace(m_pl=payload, CoG_pl=np.asarray(PAYLOAD_COG)) if payload else model


def rest_strain_shift(
    model: HsaParams, plant_sigma_a_eq: tuple[float, float] | None
) -> tuple[float, float]:
    """The plant's σ_a,eq minus the controller's ``model``'s, per rod (0 without
    ``plant_sigma_a_eq``): :func:`run_disturbance`'s ``rest_strain_shift``."""
    if plant_sigma_a_eq is None:
        return (0.0, 0.0)
    s1, s2 = np.asarray(plant_sigma_a_eq, float) - np.asarray(model.sigma_a_eq, float)
    return (float(s1), float(s2))


def run_disturbance(
    disturbance: DisturbanceModel,
    command_latency: float,
    rest_strain_shift: tuple[float, float] = (0.0, 0.0),
    command_queue: tuple[int, float] = (0, 0.0),
) -> DisturbanceModel:
    """The world of a run: ``disturbance`` with the controller side's ``command_latency`` [s]
    (tick → goal written on the bus) added to its actuation latency, its ``command_queue`` (depth,
    transaction [s]; depth 0: none) as the path its goals take to the bus
    (:mod:`hsa_core.sim.command_queue`), and the plant's σ_a,eq of rods 1 and 2 moved by
    ``rest_strain_shift`` [-] beyond the controller's model (a run whose plant and controller had
    different σ_a,eq: ExperimentConfig.plant_sigma_a_eq)."""
    if not (command_latency >= 0.0):
        raise ValueError(f"command_latency must be >= 0 s, got {command_latency}")
    s1, s2 = (float(v) for v in rest_strain_shift)
    if not (math.isfinite(s1) and math.isfinite(s2)):
        raise ValueError(f"rest_strain_shift must be finite, got {rest_strain_shift}")
    depth, transaction = command_queue
    if not (command_latency or s1 or s2 or depth):
        return disturbance
    queue = {"command_queue_depth": int(depth), "command_transaction": float(transaction)}
    return dataclasses.replace(
        disturbance,
        **(queue if depth else {}),
        actuation_latency=disturbance.actuation_latency + command_latency,
        rest_strain_offset=disturbance.rest_strain_offset + 0.5 * (s1 + s2),
        rest_strain_difference=disturbance.rest_strain_difference + (s2 - s1),
    )


def graph_arguments(
    profile: RunProfile,
    *,
    sigma_a_eq: tuple[float, float] | None = None,
    plant_sigma_a_eq: tuple[float, float] | None = None,
    payload: float | None = None,
    run: Replayable | None = None,
) -> dict[str, str]:
    """Launch arguments of sim.launch.yaml for ``profile`` (a real ``run``: its profile, material,
    law, σ_a,eq and payload); ``sigma_a_eq`` / ``payload`` override the profile's or the run's,
    ``plant_sigma_a_eq`` gives the plant its own (ExperimentConfig.plant_sigma_a_eq). The run's
    gains and setpoints are files (gains_file, sequencer_file), written by the caller."""
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
        "command_queue_depth": str(profile.command_queue_depth),
        "command_transaction": repr(profile.command_transaction_ms * 1e-3),
        "sigma_a_eq": _strains(sigma),
        "plant_sigma_a_eq": _strains(plant_sigma_a_eq),
    }
    if run is not None:
        args |= {"material": run.conditions.material, "controller": run.conditions.law.value}
    return args


def _strains(sigma: tuple[float, float] | None) -> str:
    """A σ_a,eq launch argument: "[]" (the default) or "[s1, s2]"."""
    return "[]" if sigma is None else f"[{float(sigma[0])!r}, {float(sigma[1])!r}]"


def run_schedule(run: Replayable) -> dict[str, object]:
    """A paper run's setpoints as setpoint_sequencer parameters, as its ``timed_reference`` gives
    them to the offline experiment. A step run: ``points`` [m] (flat x, y), ``times`` [s] (point
    k's instant after point 0: the real step instants where known) and ``rate`` [Hz] (the last
    point lasts 1/rate, to the end of the run). A contour run: the sequencer's own contour
    parameters (the same pipeline, :func:`hsa_core.task.trajectories.contour_reference`) at 8 Hz."""
    contour = run.contour if isinstance(run, CataloguedRun) else None
    if contour is not None:
        return {
            "trajectory": "contour",
            "image_path": str(run.image_path()),
            "centroid": list(contour.centroid),
            "radius": contour.r_max,
            "contour_k": contour.k,
            "image_threshold": contour.threshold,
            "image_invert": contour.invert,
            "image_crop_square": contour.crop_square,
            "image_flip": contour.flip,
            "direction": "traced",
            "rate": CONTOUR_RATE,
        }
    reference = run.timed_reference()
    times = [float(t) for t in reference.t]
    return {
        "trajectory": "steps",
        "points": [float(v) for v in np.asarray(reference.p_des).ravel()],
        "times": times,
        "rate": 1.0 / (reference.duration - times[-1]),
    }

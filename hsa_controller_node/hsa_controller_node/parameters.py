"""controller_node's parameters (docs/nodes/hsa_controller_node.md): the declared specs and
the checks across them.

``SPECS`` is built on first access: the gain defaults come from the packaged gains files, which
importing this module does not read.
"""

from __future__ import annotations

import functools
from typing import Any

from hsa_common.model_params import MODEL_SPECS, WIRING_SPEC
from hsa_common.parameters import ParameterValidationError, ParamSpec, typed
from hsa_controller_node import scheduling
from hsa_core.controller.control import (
    CollocatedGains,
    ControllerKind,
    EeIntegralGains,
    PidGains,
    Tuning,
    default_gains,
)
from hsa_core.controller.supervision import DRIVER_TIMEOUT, HOLD_TIMEOUT, STALE_TIMEOUT
from hsa_core.controller.validation import POSE_TOLERANCE
from hsa_core.runs.profiles import VelocityEstimator
from hsa_core.task.planning import MAX_OPTIMALITY_ERROR


def _positive(value: Any) -> str | None:
    """Strictly positive (ranges only give >= 0)."""
    return None if value > 0.0 else f"must be > 0, got {value!r}"


def _granted(priority: int) -> str | None:
    """A real-time priority the OS grants this process (0: none asked)."""
    return scheduling.refusal(priority) if priority > 0 else None


@functools.cache
def specs() -> tuple[ParamSpec, ...]:
    """The declared specs; the gain defaults are read from the packaged FPU gains files at the
    first call."""
    collocated = default_gains(ControllerKind.PSATID)
    pid = default_gains(ControllerKind.PID)
    ee = EeIntegralGains()
    return (
        *MODEL_SPECS,
        WIRING_SPEC,
        ParamSpec(
            "controller",
            ControllerKind.PSATID.value,
            "control law: P-satI-D, P-satI-D + gravity cancellation or the task-space PID baseline",
            choices=tuple(k.value for k in ControllerKind),
            read_only=True,
        ),
        ParamSpec(
            "rate",
            40.0,
            "[Hz] control rate; the integrators use dt = 1/rate unless integrator_dt is set",
            low=1.0,
            high=1000.0,
            read_only=True,
        ),
        ParamSpec(
            "integrator_dt",
            0.0,
            "[s] the integrators' step (a run profile's nominal dt); 0 = 1/rate",
            low=0.0,
            high=1.0,
            read_only=True,
        ),
        ParamSpec(
            "velocity_estimator",
            VelocityEstimator.SAVITZKY_GOLAY_20.value,
            "rates the law uses: savitzky_golay_20 = the state's (kinematics_node); "
            "smoothing_spline_16 = the September 2023 stand-in, fitted at each tick to the "
            "newest states of the last 16 ticks (hsa_core.sim.run_conditions.TickEstimator)",
            choices=tuple(v.value for v in VelocityEstimator),
            read_only=True,
        ),
        ParamSpec(
            "kp",
            collocated.kp,
            "[rad^2/(N m)] P-satI-D(+GC) proportional gain",
            low=0.0,
            high=100.0,
        ),
        ParamSpec("ki", collocated.ki, "[rad/s] P-satI-D(+GC) integral gain", low=0.0, high=100.0),
        ParamSpec(
            "kd",
            collocated.kd,
            "[rad^2 s/(N m)] P-satI-D(+GC) derivative gain",
            low=0.0,
            high=100.0,
        ),
        ParamSpec(
            "gamma",
            collocated.gamma,
            "[rad/(N m)] P-satI-D(+GC) tanh compression of the integrand (> 0)",
            low=0.0,
            high=1e5,
            validator=_positive,
        ),
        ParamSpec("kp_pid", pid.kp, "[rad/m] task-space PID proportional gain", low=0.0, high=1e4),
        ParamSpec("ki_pid", pid.ki, "[rad/(m s)] task-space PID integral gain", low=0.0, high=1e5),
        ParamSpec("kd_pid", pid.kd, "[rad s/m] task-space PID derivative gain", low=0.0, high=1e3),
        ParamSpec(
            "reset_integral_on_setpoint_change", False, "zero e_int when a new setpoint is accepted"
        ),
        ParamSpec(
            "ee_integral",
            False,
            "EE-position integral extension (§3.8; collocated laws only)",
            read_only=True,
        ),
        ParamSpec(
            "ee_ki",
            ee.ki_ee,
            "[1/s] EE-integral gain K_I,ee (time constant >= 3 s recommended)",
            low=0.0,
            high=100.0,
        ),
        ParamSpec(
            "ee_e_on",
            ee.e_on,
            "[m] EE integral runs only while |p^d - p_ee| is below this (> 0)",
            low=0.0,
            high=0.1,
            validator=_positive,
        ),
        ParamSpec("ee_z_max", ee.z_max, "[m s] clamp of each EE integral state", low=0.0, high=1.0),
        ParamSpec(
            "ee_reset_on_setpoint_change",
            ee.reset_on_setpoint_change,
            "zero the EE integral state when a new setpoint is accepted",
            read_only=True,
        ),
        ParamSpec(
            "stale_timeout",
            STALE_TIMEOUT,
            "[s] a state whose stamp is older than this "
            "(node clock) is stale: hold the last command; states stamped more than this in "
            "the future are refused",
            low=0.001,
            high=10.0,
            read_only=True,
        ),
        ParamSpec(
            "hold_timeout",
            HOLD_TIMEOUT,
            "[s] stop re-publishing the held command once the "
            "newest state is this old (>= stale_timeout)",
            low=0.001,
            high=60.0,
            read_only=True,
        ),
        ParamSpec(
            "stamp_clock",
            True,
            "state stamps are on the node clock (age judged by stamp); "
            "false only where they are not, e.g. replayed recorded stamps (age then judged "
            "by arrival)",
            read_only=True,
        ),
        ParamSpec(
            "driver_timeout",
            DRIVER_TIMEOUT,
            "[s] no phi_present from the driver for this "
            "long: driver lost, nothing is sent, integrators frozen; 0 = no driver in this "
            "graph (replay, controller-only tests)",
            low=0.0,
            high=10.0,
            read_only=True,
        ),
        ParamSpec(
            "setpoint_residual_tol",
            MAX_OPTIMALITY_ERROR,
            "[N m, N] largest ||G + K - alpha|| at (q_des, phi_ss) of an accepted setpoint (the "
            "planner's acceptance threshold)",
            low=1e-12,
            high=1.0,
            read_only=True,
        ),
        ParamSpec(
            "setpoint_pose_tol",
            POSE_TOLERANCE,
            "[m, rad] largest |chiee_des - FK(q_des)| of an accepted setpoint",
            low=1e-12,
            high=0.1,
            read_only=True,
        ),
        ParamSpec(
            "rejection_log_period",
            5.0,
            "[s] refused setpoints and states are logged at "
            "most once per period (all are counted on /diagnostics)",
            low=0.0,
            high=3600.0,
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
        ParamSpec(
            "realtime_priority",
            0,
            "SCHED_RR priority (1-99) of every thread once the node "
            "is built, so busy processes cannot delay the tick; 0 = normal scheduling. Needs "
            "CAP_SYS_NICE or an rtprio limit",
            low=0,
            high=99,
            read_only=True,
            validator=_granted,
        ),
    )


def __getattr__(name: str) -> Any:
    """``SPECS``: :func:`specs` (built on first access)."""
    if name == "SPECS":
        return specs()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def check_combination(p: dict[str, Any]) -> None:
    """Refuse what no single spec can: hold_timeout below stale_timeout, the EE integral with the
    PID."""
    if p["hold_timeout"] < p["stale_timeout"]:
        raise ParameterValidationError(
            f"parameter 'hold_timeout' ({p['hold_timeout']} s) must be >= stale_timeout "
            f"({p['stale_timeout']} s)"
        )
    if p["ee_integral"] and ControllerKind(p["controller"]) is ControllerKind.PID:
        raise ParameterValidationError(
            "parameter 'ee_integral' applies to the collocated laws only, not 'pid'"
        )


def gains(kind: ControllerKind, p: dict[str, Any]) -> CollocatedGains | PidGains:
    """The law's gains: kp, ki, kd, gamma (collocated laws) or kp_pid, ki_pid, kd_pid."""
    if kind is ControllerKind.PID:
        return typed(PidGains, p, kp="kp_pid", ki="ki_pid", kd="kd_pid")
    return typed(CollocatedGains, p)


def ee_gains(p: dict[str, Any]) -> EeIntegralGains:
    """The EE-integral gains: ee_ki, ee_e_on, ee_z_max, ee_reset_on_setpoint_change."""
    return typed(
        EeIntegralGains,
        p,
        ki_ee="ee_ki",
        e_on="ee_e_on",
        z_max="ee_z_max",
        reset_on_setpoint_change="ee_reset_on_setpoint_change",
    )


def tuning(kind: ControllerKind, p: dict[str, Any]) -> Tuning:
    """What a run-time update may change on the running controller; a bad gain is a
    ParameterValidationError."""
    law, ee = gains(kind, p), ee_gains(p)
    try:
        return Tuning(law, ee, bool(p["reset_integral_on_setpoint_change"]))
    except ValueError as exc:
        raise ParameterValidationError(f"controller gains: {exc}") from exc

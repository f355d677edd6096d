"""Control laws of the paper (planning_and_control.md §3) as pure jitted functions, plus a
NumPy-facing wrapper.

Laws (state in -> command, new state and info out):
* `p_sati_d`: collocated P-satI-D (§3.3); with ``gravity_cancellation=True`` the P-satI-D + GC law
  (§3.4);
* `task_space_pid`: the baseline task-space PID with the constant phi_max/2 feedforward (§3.5).

As in the paper: the integrators use the nominal dt, the integral term uses e_int as it was before
the tick, the collocated integrand is tanh(gamma e_y), and every law ends with phi_cmd = clip(h *
phi^d, 0, phi_max).

Extension (§3.8, off by default): integral action on the EE position for the collocated laws. The
outer integrator z <- clip(z + (p^d - p_ee) dt, -z_max, z_max) runs only while ||p^d - p_ee|| < e_on
and no rod is saturated. Its actuation offset dphi_z = K_I,ee S_ss^-1 z (S_ss from the
implicit-function theorem, once per setpoint) is added to phi^d, and the collocated reference is
shifted consistently, varphi^d <- varphi^d + T dphi_z with T = J_h,1:2(xi^d) dxi/dphi. Without that
shift the inner collocated integrator (which drives e_y to zero) would cancel any constant offset on
phi^d at steady state; with it, the pair (phi^ss + dphi_z, varphi^d + T dphi_z) is the linearised
re-plan for the corrected target, which the spec names as the equivalent alternative.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping
from functools import lru_cache, partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import yaml
from jax import Array
from jax.typing import ArrayLike

from hsa_core.controller.validation import configuration_problem, q_bounds
from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import CONFIG_DIR, HsaParams
from hsa_core.task.planning import MAX_OPTIMALITY_ERROR, Setpoint

CONTROL_DT = 0.025
"""Nominal control period of the experiments, 40 Hz [s] (§3.1)."""

INTEGRAL_LIMIT = 1e3
"""Bound on every integrator state [s, or m s for the PID and z_ee]: the collocated integrand is at
most 1, so reaching it takes 1000 s of saturated error (the PID: 1 m of error for 1000 s); it only
keeps the state finite by design."""


class ControllerKind(str, enum.Enum):
    """Control law; values are the names used on the ROS interface."""

    PSATID = "psatid"
    PSATID_GC = "psatid_gc"
    PID = "pid"


@dataclasses.dataclass(frozen=True)
class CollocatedGains:
    """P-satI-D gains (§3.3): kp [rad^2/(N m)], ki [rad/s], kd [rad^2 s/(N m)], gamma [rad/(N
    m)]."""

    kp: float
    ki: float
    kd: float
    gamma: float


@dataclasses.dataclass(frozen=True)
class PidGains:
    """Task-space PID gains (§3.5): kp [rad/m], ki [rad/(m s)], kd [rad s/m]."""

    kp: float
    ki: float
    kd: float


@dataclasses.dataclass(frozen=True)
class EeIntegralGains:
    """EE-integral extension (§3.8): ki_ee [1/s] (time constant >= 3 s), e_on [m], z_max [m s],
    optional z reset."""

    ki_ee: float = 1.0 / 3.0
    e_on: float = 3e-3
    z_max: float = 0.015
    reset_on_setpoint_change: bool = False


for _cls, _meta in (
    (CollocatedGains, []),
    (PidGains, []),
    (EeIntegralGains, ["reset_on_setpoint_change"]),
):
    _data = [f.name for f in dataclasses.fields(_cls) if f.name not in _meta]
    jax.tree_util.register_dataclass(_cls, data_fields=_data, meta_fields=_meta)

GAINS_DIR = CONFIG_DIR / "gains"
"""The paper's gains, one controller_node parameter file per material and law:
``<material>_<law>.yaml`` (§3.6)."""


def gains_file(kind: ControllerKind | str, material: str = "fpu") -> Path:
    """The packaged gains file of a law and material; materials without one use the FPU file."""
    kind = ControllerKind(kind)
    path = GAINS_DIR / f"{material}_{kind.value}.yaml"
    return path if path.is_file() else GAINS_DIR / f"fpu_{kind.value}.yaml"


def load_gains(path: str | Path, kind: ControllerKind | str) -> CollocatedGains | PidGains:
    """A law's gains from a controller_node parameter file (``/**: ros__parameters: {kp: …}``, as
    hsa_tune writes); ValueError names the file and what is missing."""
    try:
        document = yaml.safe_load(Path(path).read_text())
        values = next(iter(document.values()))["ros__parameters"]
        gains = _gains(kind, {k: float(v) for k, v in values.items() if not isinstance(v, str)})
    except (
        OSError,
        yaml.YAMLError,
        AttributeError,
        StopIteration,
        KeyError,
        TypeError,
        ValueError,
    ) as exc:
        raise ValueError(
            f"{path}: not a gains file for {ControllerKind(kind).value} ({exc!r})"
        ) from exc
    validate_gains(gains)
    return gains


@lru_cache(maxsize=None)
def default_gains(kind: ControllerKind | str, material: str = "fpu") -> CollocatedGains | PidGains:
    """The paper's gains for a law and material (§3.6), from the packaged gains file
    (:func:`gains_file`)."""
    return load_gains(gains_file(kind, material), kind)


def _gains(kind: ControllerKind | str, values: Mapping[str, float]) -> CollocatedGains | PidGains:
    """The law's gains from a gains file's values: kp, ki, kd, gamma (collocated laws) or kp_pid,
    ki_pid, kd_pid."""
    if ControllerKind(kind) is ControllerKind.PID:
        return PidGains(kp=values["kp_pid"], ki=values["ki_pid"], kd=values["kd_pid"])
    return CollocatedGains(kp=values["kp"], ki=values["ki"], kd=values["kd"], gamma=values["gamma"])


@dataclasses.dataclass(frozen=True)
class Tuning:
    """What a running controller may change: the law's gains, the EE-integral gains (taken only
    where the extension is on) and the e_int reset flag; a bad gain is a one-line ValueError."""

    gains: CollocatedGains | PidGains
    ee_gains: EeIntegralGains
    reset_integral_on_setpoint_change: bool

    def __post_init__(self) -> None:
        """Refuse gains that are not finite and >= 0 (> 0 for gamma and e_on)."""
        validate_gains(self.gains)
        validate_gains(self.ee_gains)


def retune(controller: Controller, tuning: Tuning) -> None:
    """Give a running controller new gains (EE gains if enabled) and e_int reset flag; the
    integrator state is kept and nothing is recompiled. Gains of another law are a ValueError."""
    expected = PidGains if controller.kind is ControllerKind.PID else CollocatedGains
    if not isinstance(tuning.gains, expected):
        raise ValueError(
            f"controller '{controller.kind.value}' needs {expected.__name__}, got "
            f"{type(tuning.gains).__name__}"
        )
    controller.gains = tuning.gains
    if controller.ee_integral is not None:
        controller.ee_integral = tuning.ee_gains
    controller.reset_integral_on_setpoint_change = tuning.reset_integral_on_setpoint_change


def validate_gains(gains: CollocatedGains | PidGains | EeIntegralGains) -> None:
    """Raise ValueError naming the first gain that is not finite and >= 0 (> 0 for gamma and
    e_on)."""
    for field in dataclasses.fields(gains):
        value = getattr(gains, field.name)
        if field.name == "reset_on_setpoint_change":
            continue
        strict = field.name in ("gamma", "e_on")
        ok = (
            isinstance(value, (int, float))
            and math.isfinite(value)
            and (value > 0.0 if strict else value >= 0.0)
        )
        if not ok:
            bound = "> 0" if strict else ">= 0"
            raise ValueError(
                f"gain '{field.name}' of {type(gains).__name__} must be finite and {bound}, got "
                f"{value!r}"
            )


class ControlReference(NamedTuple):
    """Per-setpoint constants of the laws (computed once per setpoint by `make_reference`).

    chiee^d, q^d, phi^ss; varphi^d = h(xi^d; phi^ss); G(xi^d) for GC; for the extension S_ss^-1
    [rad/m] and T.
    """

    chiee_des: Array
    q_des: Array
    phi_ss: Array
    varphi_des: Array
    gravity_des: Array
    ee_gain: Array
    varphi_shift: Array


class Measurement(NamedTuple):
    """Inputs of one tick: q, q_dot (IK + estimator) and chiee, chiee_dot (mocap + estimator)."""

    q: Array
    q_dot: Array
    chiee: Array
    chiee_dot: Array


class ControllerState(NamedTuple):
    """Integrator states: e_int (2,) [s for collocated laws, m s for the PID] and z_ee (2,) [m
    s]."""

    e_int: Array
    z_ee: Array


class ControllerInfo(NamedTuple):
    """Every intermediate quantity of a tick (NaN where a law does not compute it); states are after
    the tick."""

    chiee: Array
    chiee_des: Array
    q: Array
    q_des: Array
    varphi: Array
    varphi_des: Array
    e_int: Array
    z_ee: Array
    phi_ss: Array
    phi_des_unsat: Array
    phi_des_sat: Array
    saturated: Array
    g_varphi: Array
    g_varphi_des: Array


_INFO_SIZES = (3, 3, 3, 3, 3, 3, 2, 2, 2, 2, 2, 1, 2, 2)


def initial_state() -> ControllerState:
    """Zero integrator states (§3.1)."""
    return ControllerState(jnp.zeros(2), jnp.zeros(2))


@jax.jit
def ee_integral_maps(params: HsaParams, q_des: ArrayLike, phi_ss: ArrayLike) -> tuple[Array, Array]:
    """Steady-state sensitivities at the setpoint: S_ss = dp_ee/dphi (2x2, m/rad) and T =
    dvarphi_1:2/dphi (2x2)."""
    q_des, phi_ss = jnp.asarray(q_des), jnp.asarray(phi_ss)
    K_t = jax.jacfwd(dynamics.static_residual, argnums=1)(params, q_des, phi_ss)
    dq_dphi = jnp.linalg.solve(K_t, dynamics.actuation_jacobian(params, q_des, phi_ss))
    S_ss = kinematics.end_effector_jacobian(params, q_des)[:2] @ dq_dphi
    T = dynamics.collocated_jacobian(params, q_des, phi_ss)[:2] @ dq_dphi
    return S_ss, T


@jax.jit
def _setpoint_terms(params: HsaParams, q_des: Array, phi_ss: Array) -> tuple[Array, Array]:
    """varphi^d = h(xi^d; phi^ss) and G(xi^d): constant while a setpoint is active."""
    return dynamics.collocated_map(params, q_des, phi_ss), dynamics.gravity_vector(params, q_des)


def make_reference(
    params: HsaParams, setpoint: Setpoint, *, ee_integral: bool = False
) -> ControlReference:
    """Per-setpoint constants for the laws; with ee_integral also S_ss^-1 and T of the §3.8
    extension."""
    chiee_des, q_des, phi_ss = (
        jnp.asarray(v, dtype=jnp.float64)
        for v in (setpoint.chiee_des, setpoint.q_des, setpoint.phi_ss)
    )
    varphi_des, gravity_des = _setpoint_terms(params, q_des, phi_ss)
    if ee_integral:
        S_ss, T = ee_integral_maps(params, q_des, phi_ss)
        ee_gain = jnp.asarray(np.linalg.inv(np.asarray(S_ss)))
    else:
        ee_gain, T = jnp.zeros((2, 2)), jnp.zeros((2, 2))
    return ControlReference(chiee_des, q_des, phi_ss, varphi_des, gravity_des, ee_gain, T)


def _saturate(params: HsaParams, phi_des: Array) -> tuple[Array, Array]:
    """phi_cmd = clip(h * phi^d, 0, phi_max) and whether any rod was clipped (§3.1)."""
    limit = params.phi_limit
    phi_h = limit.h * phi_des
    phi_cmd = limit.clip(phi_h)
    return phi_cmd, jnp.any(phi_cmd != phi_h)


@partial(jax.jit, static_argnames=("gravity_cancellation",))
def p_sati_d(
    params: HsaParams,
    gains: CollocatedGains,
    ref: ControlReference,
    state: ControllerState,
    meas: Measurement,
    dt: ArrayLike,
    gravity_cancellation: bool = False,
    ee_integral: EeIntegralGains | None = None,
) -> tuple[Array, ControllerState, ControllerInfo]:
    """P-satI-D (§3.3), optionally + GC (§3.4) and the EE integral (§3.8); returns (phi_cmd, new
    state, info)."""
    phi_ss = ref.phi_ss
    varphi = dynamics.collocated_map(params, meas.q, phi_ss)
    varphi_des = ref.varphi_des
    J_h = dynamics.collocated_jacobian(params, meas.q, phi_ss)
    varphi_dot = J_h @ meas.q_dot
    e_y = varphi_des[:2] - varphi[:2]
    feedforward = phi_ss
    nan2 = jnp.full(2, jnp.nan)
    g_varphi, g_varphi_des = nan2, nan2
    if gravity_cancellation:
        G = jnp.stack([dynamics.gravity_vector(params, meas.q), ref.gravity_des], axis=1)
        G_varphi = jnp.linalg.solve(J_h.T, G)  # J_h at the current xi for both terms
        g_varphi, g_varphi_des = G_varphi[:2, 0], G_varphi[:2, 1]
        feedforward = feedforward - g_varphi_des + g_varphi
    if ee_integral is not None:
        dphi_z = ee_integral.ki_ee * ref.ee_gain @ state.z_ee
        feedforward = feedforward + dphi_z
        e_y = e_y + ref.varphi_shift @ dphi_z
    phi_des = feedforward + gains.kp * e_y - gains.kd * varphi_dot[:2] + gains.ki * state.e_int
    e_int = state.e_int + jnp.tanh(gains.gamma * e_y) * dt
    phi_cmd, saturated = _saturate(params, phi_des)
    z_ee = state.z_ee
    if ee_integral is not None:
        e_ee = ref.chiee_des[:2] - meas.chiee[:2]
        active = (jnp.linalg.norm(e_ee) < ee_integral.e_on) & ~saturated
        z_ee = jnp.clip(
            z_ee + jnp.where(active, e_ee * dt, 0.0), -ee_integral.z_max, ee_integral.z_max
        )
    new_state = ControllerState(e_int, z_ee)
    info = ControllerInfo(
        meas.chiee,
        ref.chiee_des,
        meas.q,
        ref.q_des,
        varphi,
        varphi_des,
        e_int,
        z_ee,
        phi_ss,
        phi_des,
        phi_cmd,
        saturated,
        g_varphi,
        g_varphi_des,
    )
    return phi_cmd, new_state, info


@jax.jit
def task_space_pid(
    params: HsaParams,
    gains: PidGains,
    ref: ControlReference,
    state: ControllerState,
    meas: Measurement,
    dt: ArrayLike,
) -> tuple[Array, ControllerState, ControllerInfo]:
    """Baseline task-space PID with constant feedforward phi_max/2 on measured EE positions
    (§3.5)."""
    e = ref.chiee_des[:2] - meas.chiee[:2]
    u = gains.kp * e + gains.ki * state.e_int - gains.kd * meas.chiee_dot[:2]
    phi_ss = params.phi_max / 2.0
    phi_des = phi_ss + jnp.array([[1.0, 1.0], [-1.0, 1.0]]) @ u
    phi_cmd, saturated = _saturate(params, phi_des)
    new_state = ControllerState(state.e_int + e * dt, state.z_ee)
    nan2, nan3 = jnp.full(2, jnp.nan), jnp.full(3, jnp.nan)
    info = ControllerInfo(
        meas.chiee,
        ref.chiee_des,
        meas.q,
        ref.q_des,
        nan3,
        nan3,
        new_state.e_int,
        new_state.z_ee,
        phi_ss,
        phi_des,
        phi_cmd,
        saturated,
        nan2,
        nan2,
    )
    return phi_cmd, new_state, info


@partial(jax.jit, static_argnames=("kind",))
def _packed_tick(
    kind: ControllerKind,
    params: HsaParams,
    gains: CollocatedGains | PidGains,
    ee_integral: EeIntegralGains | None,
    ref: ControlReference,
    state: Array,
    meas: Array,
    dt: ArrayLike,
) -> Array:
    """One tick on flat arrays: meas = [q, q_dot, chiee, chiee_dot], state = [e_int, z_ee] ->
    [phi_cmd, info...]."""
    m = Measurement(meas[0:3], meas[3:6], meas[6:9], meas[9:12])
    s = ControllerState(state[0:2], state[2:4])
    if kind is ControllerKind.PID:
        phi_cmd, _, info = task_space_pid(params, gains, ref, s, m, dt)
    else:
        gc = kind is ControllerKind.PSATID_GC
        phi_cmd, _, info = p_sati_d(
            params, gains, ref, s, m, dt, gravity_cancellation=gc, ee_integral=ee_integral
        )
    fields = [jnp.atleast_1d(jnp.asarray(v, dtype=jnp.float64)) for v in info]
    return jnp.concatenate([phi_cmd, *fields])


class Controller:
    """NumPy-facing controller: validates gains, compiles in the constructor, keeps the integrator
    state."""

    def __init__(
        self,
        kind: ControllerKind | str,
        params: HsaParams,
        gains: CollocatedGains | PidGains | None = None,
        dt: float = CONTROL_DT,
        *,
        ee_integral: EeIntegralGains | None = None,
        reset_integral_on_setpoint_change: bool = False,
    ) -> None:
        """Configure one law; ee_integral enables the §3.8 extension (collocated laws only)."""
        self.kind = ControllerKind(kind)
        gains = default_gains(self.kind, params.material) if gains is None else gains
        expected = PidGains if self.kind is ControllerKind.PID else CollocatedGains
        if not isinstance(gains, expected):
            raise ValueError(
                f"controller '{self.kind.value}' needs {expected.__name__}, got "
                f"{type(gains).__name__}"
            )
        validate_gains(gains)
        if ee_integral is not None:
            if self.kind is ControllerKind.PID:
                raise ValueError(
                    "the EE-integral extension applies to the collocated laws only, not 'pid'"
                )
            validate_gains(ee_integral)
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0, got {dt!r}")
        self.params = params
        self.gains = gains
        self.ee_integral = ee_integral
        self.dt = float(dt)
        self.reset_integral_on_setpoint_change = bool(reset_integral_on_setpoint_change)
        self._phi_lo, self._phi_hi = params.phi_limit.box
        self._q_bounds = q_bounds(params)
        self._state = np.zeros(4)
        self._setpoint: Setpoint | None = None
        self._ref: ControlReference | None = None
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile the tick (and the per-setpoint maps) with inputs of the final shapes, then clear
        everything."""
        rest = Setpoint(np.zeros(3), np.zeros(3), 0.5 * (self._phi_lo + self._phi_hi), 0.0)
        self.set_setpoint(rest)
        self.step(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
        self._setpoint, self._ref = None, None
        self.reset()

    @property
    def setpoint(self) -> Setpoint | None:
        """The active setpoint (None before the first one)."""
        return self._setpoint

    @property
    def state(self) -> ControllerState:
        """Copy of the integrator state [e_int, z_ee]."""
        return ControllerState(self._state[:2].copy(), self._state[2:].copy())

    def reset(self) -> None:
        """Zero both integrators."""
        self._state = np.zeros(4)

    def set_setpoint(self, setpoint: Setpoint) -> None:
        """Activate a setpoint after the sanity checks of §5 (finite, 0 <= ||r|| <= 1e-3, phi^ss in
        [0, phi_max], q^d plausible); the model consistency check is
        hsa_core.controller.validation.SetpointValidator."""
        chiee_des, q_des, phi_ss = (
            np.asarray(v, dtype=np.float64)
            for v in (setpoint.chiee_des, setpoint.q_des, setpoint.phi_ss)
        )
        if chiee_des.shape != (3,) or q_des.shape != (3,) or phi_ss.shape != (2,):
            raise ValueError("setpoint needs chiee_des (3,), q_des (3,) and phi_ss (2,)")
        if not (
            np.all(np.isfinite(chiee_des))
            and np.all(np.isfinite(q_des))
            and np.all(np.isfinite(phi_ss))
        ):
            raise ValueError("setpoint contains non-finite values")
        if not 0.0 <= setpoint.optimality_error <= MAX_OPTIMALITY_ERROR:
            raise ValueError(
                f"setpoint optimality error {setpoint.optimality_error!r} outside "
                f"[0, {MAX_OPTIMALITY_ERROR:g}]"
            )
        if (problem := configuration_problem(q_des, self._q_bounds)) is not None:
            raise ValueError(f"setpoint {problem}")
        if np.any(phi_ss < self._phi_lo) or np.any(phi_ss > self._phi_hi):
            raise ValueError(f"setpoint phi_ss {phi_ss.tolist()} outside [0, phi_max]")
        self._ref = make_reference(self.params, setpoint, ee_integral=self.ee_integral is not None)
        if self._setpoint is not None:
            if self.reset_integral_on_setpoint_change:
                self._state[:2] = 0.0
            if self.ee_integral is not None and self.ee_integral.reset_on_setpoint_change:
                self._state[2:] = 0.0
        self._setpoint = setpoint

    def step(
        self,
        q: ArrayLike,
        q_dot: ArrayLike,
        chiee: ArrayLike,
        chiee_dot: ArrayLike,
        setpoint: Setpoint | None = None,
    ) -> tuple[np.ndarray, ControllerInfo]:
        """One control tick; a setpoint other than the active one is activated first. Returns
        (phi_cmd, info).

        Non-finite measurements raise ValueError before anything changes (NaN would otherwise enter
        the integrators). The integrator state stays finite and within +-INTEGRAL_LIMIT by
        construction: a tick whose command or new state is not finite raises ValueError and leaves
        the state as it was."""
        if setpoint is not None and setpoint is not self._setpoint:
            self.set_setpoint(setpoint)
        if self._ref is None:
            raise RuntimeError(
                "no setpoint yet: the controller sends no output before the first setpoint (§3.1)"
            )
        meas = np.concatenate(
            [
                np.asarray(q, np.float64),
                np.asarray(q_dot, np.float64),
                np.asarray(chiee, np.float64),
                np.asarray(chiee_dot, np.float64),
            ]
        )
        if meas.shape != (12,):
            raise ValueError("q, q_dot, chiee and chiee_dot must have 3 elements each")
        if not np.all(np.isfinite(meas)):
            raise ValueError(
                "measurement contains non-finite values: refused, the controller state is unchanged"
            )
        out = np.asarray(
            _packed_tick(
                self.kind,
                self.params,
                self.gains,
                self.ee_integral,
                self._ref,
                self._state,
                meas,
                self.dt,
            )
        )
        fields, k = [], 2
        for size in _INFO_SIZES:
            fields.append(out[k : k + size])
            k += size
        fields[11] = bool(fields[11][0])
        new_state = np.concatenate([fields[6], fields[7]])
        if not (np.all(np.isfinite(out[:2])) and np.all(np.isfinite(new_state))):
            raise ValueError(
                "non-finite command or integrator state: tick refused, the controller state is "
                "unchanged"
            )
        new_state = np.clip(new_state, -INTEGRAL_LIMIT, INTEGRAL_LIMIT)
        fields[6], fields[7] = new_state[:2], new_state[2:]
        self._state = new_state
        return out[:2], ControllerInfo(*fields)

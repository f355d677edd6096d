"""Model verification by open-loop replay of a recorded phi(t) (identification.md §6, the paper's
GBN verification).

The measured twist is held (zero-order hold) over each interval of a uniform grid with the mean
mocap period; the model is integrated with the Dormand-Prince 5(4) pair at a fixed 0.1 ms step (the
paper's setting; the embedded error estimate is not used) from the measured initial configuration,
and the simulated EE pose chiee and configuration q are compared with the measured ones (q = IK of
the measured pose with the same rest strains). Metrics over the whole record (§6, "recommended
metrics"): RMSE per coordinate, RMSE normalised by the measured range, maximum error, and the best
time lag (one shift for all channels, minimising the sum of range-normalised squared errors) with
the RMSE after removing it.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from hsa_core.model import kinematics
from hsa_core.model.dynamics import forward_dynamics_fn
from hsa_core.model.params import HsaParams
from hsa_core.sysid.excitation import zero_order_hold

DOPRI_DT = 1e-4
"""Fixed integration step of the replay [s] (the paper: Dormand-Prince 5(4) at 0.1 ms)."""

CHANNELS = ("x", "y", "theta", "kappa_be", "sigma_sh", "sigma_ax")
"""Compared coordinates: chiee = [x, y, theta], then q = [kappa_be, sigma_sh, sigma_ax]."""

# Dormand-Prince 5(4) tableau: nodes c, stage matrix a, 5th-order weights b (Dormand & Prince 1980)
_C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0)
_A = (
    (),
    (1 / 5,),
    (3 / 40, 9 / 40),
    (44 / 45, -56 / 15, 32 / 9),
    (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
    (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
)
_B = (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84)


def dopri5_step(f, x: Array, dt: ArrayLike) -> Array:  # noqa: ANN001 - f: state -> state derivative
    """One fixed Dormand-Prince 5(4) step of x_dot = f(x), advancing with the 5th-order solution."""
    ks: list[Array] = []
    for row in _A:
        xi = x + dt * sum((a * k for a, k in zip(row, ks)), jnp.zeros_like(x))
        ks.append(f(xi))
    return x + dt * sum(b * k for b, k in zip(_B, ks))


def replay(
    params: HsaParams, x0: ArrayLike, phi_seq: ArrayLike, dt_hold: float, dt: float = DOPRI_DT
) -> Array:
    """States [q, q_dot] (N + 1, 6) at the hold boundaries: phi_seq[k] (N, 2) held dt_hold s, Dopri5
    steps of ~dt."""
    substeps = max(1, round(dt_hold / dt))
    h = dt_hold / substeps
    return _replay(
        params,
        jnp.asarray(x0, dtype=jnp.float64),
        jnp.asarray(phi_seq, dtype=jnp.float64),
        h,
        substeps,
    )


@functools.partial(jax.jit, static_argnames=("substeps",))
def _replay(params: HsaParams, x0: Array, phi_seq: Array, h: Array, substeps: int) -> Array:
    """Compiled replay loop of :func:`replay`."""
    q_ddot = forward_dynamics_fn(params)

    def hold(x: Array, phi: Array) -> tuple[Array, Array]:
        def f(s: Array) -> Array:
            return jnp.concatenate([s[3:], q_ddot(s[:3], s[3:], phi)])

        x = jax.lax.fori_loop(0, substeps, lambda _, s: dopri5_step(f, s, h), x)
        return x, x

    _, xs = jax.lax.scan(hold, x0, phi_seq)
    return jnp.concatenate([x0[None], xs])


@jax.jit
def _poses_of(params: HsaParams, qs: Array) -> Array:
    """FK of a batch of configurations."""
    return jax.vmap(lambda q: kinematics.end_effector_pose(params, q))(qs)


@jax.jit
def _configurations_of(params: HsaParams, chiee: Array) -> Array:
    """IK of a batch of poses."""
    return jax.vmap(lambda c: kinematics.inverse_kinematics(params, c))(chiee)


@dataclasses.dataclass(frozen=True)
class Verification:
    """Measured and simulated channels on the replay grid, with the metrics of identification.md
    §6."""

    t: np.ndarray
    measured: np.ndarray
    simulated: np.ndarray
    phi: np.ndarray
    rmse: dict[str, float]
    nrmse: dict[str, float]
    max_error: dict[str, float]
    lag: float
    rmse_lagged: dict[str, float]


def _metrics(measured: np.ndarray, simulated: np.ndarray) -> tuple[dict, dict, dict]:
    """RMSE, range-normalised RMSE and maximum absolute error per channel."""
    err = simulated - measured
    rmse = np.sqrt(np.mean(err**2, axis=0))
    span = np.ptp(measured, axis=0)
    nrmse = np.where(span > 0.0, rmse / np.where(span > 0.0, span, 1.0), np.nan)
    return (
        dict(zip(CHANNELS, rmse.tolist())),
        dict(zip(CHANNELS, nrmse.tolist())),
        dict(zip(CHANNELS, np.max(np.abs(err), axis=0).tolist())),
    )


def best_lag(measured: np.ndarray, simulated: np.ndarray, max_shift: int) -> int:
    """Shift s (samples; > 0: the simulation lags) minimising the summed range-normalised MSE of
    sim[k+s] - meas[k]."""
    span = np.ptp(measured, axis=0)
    span = np.where(span > 0.0, span, 1.0)
    n = len(measured)
    costs = {}
    for s in range(-max_shift, max_shift + 1):
        a, b = (measured[: n - s], simulated[s:]) if s >= 0 else (measured[-s:], simulated[: n + s])
        costs[s] = float(np.sum(np.mean(((b - a) / span) ** 2, axis=0)))
    return min(costs, key=lambda s: (costs[s], abs(s)))


def verify(
    params: HsaParams,
    t: ArrayLike,
    chiee: ArrayLike,
    phi: ArrayLike,
    q_dot0: ArrayLike | None = None,
    dt: float = DOPRI_DT,
    max_lag: float = 0.1,
) -> Verification:
    """Replay the measured phi (N, 2) at stamps t (N,) through the model and compare with the
    measured poses (N, 3).

    The grid is t0 + k dt_d with dt_d the mean sample period; phi is taken by zero-order hold and
    the poses by linear interpolation on it. The initial configuration is the IK of the first pose,
    its rate q_dot0 (default 0: records start at rest).
    """
    t, chiee, phi = np.asarray(t, float), np.asarray(chiee, float), np.asarray(phi, float)
    if len(t) < 3 or np.any(np.diff(t) <= 0.0):
        raise ValueError("verification needs at least 3 samples with increasing stamps")
    dt_d = float(np.mean(np.diff(t)))
    grid = t[0] + dt_d * np.arange(int(round((t[-1] - t[0]) / dt_d)) + 1)
    poses = np.stack([np.interp(grid, t, chiee[:, i]) for i in range(3)], axis=1)
    phi_grid = zero_order_hold(t, phi, grid)
    q_meas = np.asarray(_configurations_of(params, jnp.asarray(poses)))
    x0 = np.concatenate([q_meas[0], np.zeros(3) if q_dot0 is None else np.asarray(q_dot0, float)])
    xs = np.asarray(replay(params, x0, phi_grid[:-1], dt_d, dt))
    sim = np.concatenate([np.asarray(_poses_of(params, jnp.asarray(xs[:, :3]))), xs[:, :3]], axis=1)
    meas = np.concatenate([poses, q_meas], axis=1)
    rmse, nrmse, max_err = _metrics(meas, sim)
    shift = best_lag(meas, sim, max(0, int(round(max_lag / dt_d))))
    n = len(meas)
    a, b = (meas[: n - shift], sim[shift:]) if shift >= 0 else (meas[-shift:], sim[: n + shift])
    return Verification(
        grid - grid[0], meas, sim, phi_grid, rmse, nrmse, max_err, shift * dt_d, _metrics(a, b)[0]
    )


def excitation_start(result: Verification, tol: float = 2e-3) -> float:
    """Time [s] of the first change of the replayed phi (0 if it never changes): where a figure
    window should start."""
    change = np.flatnonzero(np.any(np.abs(np.diff(result.phi, axis=0)) > tol, axis=1))
    return float(result.t[change[0] + 1]) if len(change) else 0.0


def format_table(results: dict[str, Verification]) -> str:
    """RMSE table (units: mm, mm, rad, 1/m, -, -), one row per verified record, with
    range-normalised values."""
    scale = {"x": 1e3, "y": 1e3}
    head = "record".ljust(24) + "".join(f"{c:>20s}" for c in CHANNELS) + f"{'lag [ms]':>10s}"
    lines = [head, " " * 24 + "".join(f"{'RMSE (range %)':>20s}" for _ in CHANNELS)]
    for name, res in results.items():
        cells = "".join(
            f"{res.rmse[c] * scale.get(c, 1.0):11.4g} ({100 * res.nrmse[c]:5.2f}%)"
            for c in CHANNELS
        )
        lines.append(f"{name[:24]:24s}{cells}{res.lag * 1e3:10.1f}")
    lines.append(
        "units: x, y in mm; theta in rad; kappa_be in 1/m; sigma_sh, sigma_ax dimensionless; RMSE "
        "after removing the lag: "
        + "; ".join(
            f"{n}: "
            + ", ".join(f"{c} {r.rmse_lagged[c] * scale.get(c, 1.0):.3g}" for c in CHANNELS)
            for n, r in results.items()
        )
    )
    return "\n".join(lines)


def plot(
    result: Verification,
    path: Path,
    window: tuple[float, float] | None = (0.0, 4.0),
    title: str = "",
) -> Path:
    """The paper's verification figure: strains (kappa left, sigma_sh and sigma_ax right) and EE
    pose (x, y in mm left, theta right), measured solid, simulated dashed, over `window` s (None:
    the whole record)."""
    from hsa_core.analysis.plotting import save, subplots  # matplotlib only where a figure is drawn

    t = result.t
    if window is None:
        window = (float(t[0]), float(t[-1]))
    sel = (t >= window[0]) & (t <= window[1])
    fig, (ax_q, ax_p) = subplots(2, 1, figsize=(8, 7), sharex=True)
    panels = (
        (ax_q, (3,), (4, 5), "kappa_be [1/m]", "sigma [-]", 1.0),
        (ax_p, (0, 1), (2,), "EE position [mm]", "theta_ee [rad]", 1e3),
    )
    for ax, left, right, ylabel_l, ylabel_r, scale in panels:
        ax_r = ax.twinx()
        for axis, idx, s in ((ax, left, scale), (ax_r, right, 1.0)):
            for i in idx:
                color = f"C{i}"
                axis.plot(
                    t[sel],
                    result.measured[sel, i] * s,
                    "-",
                    color=color,
                    label=f"{CHANNELS[i]} measured",
                )
                axis.plot(
                    t[sel],
                    result.simulated[sel, i] * s,
                    "--",
                    color=color,
                    label=f"{CHANNELS[i]} simulated",
                )
        ax.set_ylabel(ylabel_l)
        ax_r.set_ylabel(ylabel_r)
        handles = ax.get_legend_handles_labels()[0] + ax_r.get_legend_handles_labels()[0]
        ax.legend(handles=handles, fontsize=7, ncol=2, loc="upper left")
    ax_p.set_xlabel("t [s]")
    ax_q.set_title(title or "model verification: measured (solid) vs simulated (dashed)")
    return save(fig, path)

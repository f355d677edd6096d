"""The experiment's metrics, the command effort and the limit-cycle classification of a batch of
closed-loop runs, in JAX: one compiled call maps a batch of
:class:`~hsa_core.sim.closed_loop.TickLog` to a batch of metric arrays.

Definitions are those of :func:`hsa_core.sim.closed_loop.evaluate`
(:mod:`hsa_core.analysis.metrics`, the reference in Python),
:func:`hsa_core.apps.robustness.classify` and :func:`hsa_core.apps.tune.effort`, over the same
window (:func:`window`, as :func:`hsa_core.sim.closed_loop.metrics_window`: from the first tick the
law ran, ``n_eval`` ticks, fewer where the log ends first). A run whose measured or desired
positions in the window are not all finite (where ``evaluate`` raises) has ``finite`` false and NaN
metrics; its classification and effort are still given. Steps are found per run, as the reference
finds them, so runs with different setpoints (e.g. each plant its own) share one call.

The window holds ``n_eval`` ticks, all of them before the run's duration (t_k = k·period <
n_eval·period), so the duration trims nothing; every tick of the window may start a step, so the
per-step sums are segment sums over ``n_eval`` segments. Everything is float64 (the caller runs
:func:`hsa_core.jaxsetup.configure_jax`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from hsa_core.analysis.metrics import RESPONSE_FRACTION, SETTLING_FLOOR, STEADY_STATE_WINDOW
from hsa_core.sim import closed_loop

UNSTABLE_M = 0.02
"""[m] mean error over a step's last 2 s above which a run counts as unstable."""
OSCILLATION_PTP_M = 2e-3
"""[m] peak-to-peak of x or y over a step's last 2 s above which a run counts as limit-cycling."""


class RunSummary(NamedTuple):
    """Per run (leading batch axis where batched): the scalar fields of
    :class:`hsa_core.analysis.metrics.RunMetrics` [SI], ``finite`` (metrics defined), the mean
    command effort |Δφ| per tick [rad] and the classification."""

    finite: Array
    rmse: Array
    n_ticks: Array
    control_rate: Array
    saturated_fraction: Array
    response_time_mean: Array
    n_not_reached: Array  # -1 where not finite
    settling_time_mean: Array
    overshoot_mean: Array
    overshoot_percent_mean: Array
    steady_state_error_mean: Array
    effort: Array
    unstable: Array
    limit_cycle: Array


def window(spec: closed_loop.LoopSpec, log: closed_loop.TickLog) -> tuple[Array, Array]:
    """Row index into one run's log of each of the ``n_eval`` window ticks (clamped to the log) and
    whether the log has that row."""
    rows = log.ran.shape[0]
    index = jnp.argmax(log.ran) + jnp.arange(spec.n_eval)
    return jnp.minimum(index, rows - 1), index < rows


def _nanmean(values: Array, mask: Array) -> Array:
    """Mean of ``values`` where ``mask`` and not NaN; NaN if none."""
    use = mask & ~jnp.isnan(values)
    count = jnp.sum(use)
    return jnp.where(
        count > 0, jnp.sum(jnp.where(use, values, 0.0)) / jnp.maximum(count, 1), jnp.nan
    )


def run_summary(spec: closed_loop.LoopSpec, log: closed_loop.TickLog) -> RunSummary:
    """The summary of one run (pure, traceable: ``jax.vmap`` it, or call :func:`evaluate` for a
    batch)."""
    n_eval = spec.n_eval
    index, valid = window(spec, log)
    # the tick times and the duration exactly as closed_loop.evaluate builds them
    t_host = (np.arange(n_eval) * spec.period_ms * closed_loop.MS) * 1e-9
    duration = n_eval * spec.period_ms * 1e-3
    t = jnp.asarray(t_host)
    # t of a step's end tick, the duration after the last
    t_after = jnp.asarray(np.append(t_host, duration))
    k = jnp.arange(n_eval)
    p_ee = log.chiee[index, :2]
    p_des = log.chiee_des[index, :2]
    true = log.true_chiee[index, :2]
    n = jnp.sum(valid)
    finite = (n >= 2) & jnp.all(~valid[:, None] | (jnp.isfinite(p_ee) & jnp.isfinite(p_des)))

    # steps: a step starts at tick 0 and wherever the setpoint changes
    change = valid & (k > 0) & jnp.any(p_des != jnp.roll(p_des, 1, axis=0), axis=1)
    step = jnp.where(valid, jnp.cumsum(change), n_eval)  # out of range: dropped by the segment sums

    def seg_sum(x: Array) -> Array:
        return jax.ops.segment_sum(x, step, n_eval, indices_are_sorted=True)

    def seg_max(x: Array) -> Array:
        return jax.ops.segment_max(x, step, n_eval, indices_are_sorted=True)

    def seg_min(x: Array) -> Array:
        return jax.ops.segment_min(x, step, n_eval, indices_are_sorted=True)

    count = seg_sum(valid.astype(jnp.int32))
    present = count > 0
    start = jnp.minimum(seg_min(jnp.where(valid, k, n_eval)), n_eval - 1)
    stop = start + count
    t_start = t[start]
    t_end = jnp.where(stop < n, t_after[jnp.minimum(stop, n_eval)], duration)
    at = jnp.minimum(step, n_eval - 1)  # each tick's step, for the per-tick broadcast

    diff = p_des - p_ee
    err = jnp.sqrt(diff[:, 0] ** 2 + diff[:, 1] ** 2)
    e0 = err[start]
    e0_k = e0[at]
    first_below = seg_min(jnp.where(valid & (err < RESPONSE_FRACTION * e0_k), k, n_eval))
    response = jnp.where(
        e0 == 0.0,
        0.0,
        jnp.where(first_below < n_eval, t[jnp.minimum(first_below, n_eval - 1)] - t_start, jnp.nan),
    )
    outside = valid & (err > jnp.maximum(RESPONSE_FRACTION * e0_k, SETTLING_FLOOR))
    last_out = seg_max(jnp.where(outside, k, -1))
    settling = jnp.where(
        last_out < 0,
        0.0,
        jnp.where(
            last_out == stop - 1, jnp.nan, t_after[jnp.clip(last_out + 1, 0, n_eval)] - t_start
        ),
    )
    target = p_des[start]
    previous = jnp.where((start > 0)[:, None], p_des[jnp.maximum(start - 1, 0)], p_ee[0])
    vec = target - previous
    size = jnp.sqrt(vec[:, 0] ** 2 + vec[:, 1] ** 2)
    direction = vec / jnp.where(size > 0.0, size, 1.0)[:, None]
    along = jnp.sum((p_ee - target[at]) * direction[at], axis=1)
    overshoot = jnp.where(
        size > 0.0, jnp.maximum(0.0, seg_max(jnp.where(valid, along, -jnp.inf))), jnp.nan
    )
    overshoot_percent = 100.0 * overshoot / jnp.where(size > 0.0, size, 1.0)
    late = valid & (t >= t_end[at] - STEADY_STATE_WINDOW)
    n_late = seg_sum(late.astype(jnp.int32))
    steady = jnp.where(
        n_late > 0,
        seg_sum(jnp.where(late, err, 0.0)) / jnp.maximum(n_late, 1),
        seg_sum(jnp.where(valid, err, 0.0)) / jnp.maximum(count, 1),
    )
    later = present & (jnp.arange(n_eval) >= 1)

    def nan_unless_finite(x: Array) -> Array:
        return jnp.where(finite, x, jnp.nan)

    rmse = jnp.sqrt(
        jnp.sum(jnp.where(valid, diff[:, 0] ** 2 + diff[:, 1] ** 2, 0.0)) / jnp.maximum(n, 1)
    )
    saturated = jnp.sum(valid & log.saturated[index]) / jnp.maximum(n, 1)
    rate = (n - 1) / t[jnp.maximum(n - 1, 0)]

    # classification, from the noise-free position in each step's last STEADY_STATE_WINDOW of ticks
    tail_ticks = round(STEADY_STATE_WINDOW / (spec.period_ms * 1e-3))
    tail = valid & (k >= stop[at] - tail_ticks)
    true_err = jnp.linalg.norm(true - p_des, axis=1)
    tail_mean = seg_sum(jnp.where(tail, true_err, 0.0)) / jnp.maximum(
        seg_sum(tail.astype(jnp.int32)), 1
    )
    ptp = seg_max(jnp.where(tail[:, None], true, -jnp.inf)) - seg_min(
        jnp.where(tail[:, None], true, jnp.inf)
    )
    true_finite = jnp.all(~valid[:, None] | jnp.isfinite(true))
    unstable = ~true_finite | jnp.any(present & (tail_mean > UNSTABLE_M))
    cycling = (
        true_finite & ~unstable & jnp.any(present & (jnp.max(ptp, axis=1) > OSCILLATION_PTP_M))
    )

    phi = log.phi_cmd[index]
    moved = (valid & (k > 0))[:, None]
    effort = jnp.where(
        n > 1,
        jnp.sum(jnp.where(moved, jnp.abs(phi - jnp.roll(phi, 1, axis=0)), 0.0))
        / jnp.maximum((n - 1) * phi.shape[1], 1),
        0.0,
    )
    return RunSummary(
        finite=finite,
        rmse=nan_unless_finite(rmse),
        n_ticks=n,
        control_rate=nan_unless_finite(rate),
        saturated_fraction=nan_unless_finite(saturated),
        response_time_mean=nan_unless_finite(_nanmean(response, later)),
        n_not_reached=jnp.where(finite, jnp.sum(later & jnp.isnan(response)), -1),
        settling_time_mean=nan_unless_finite(_nanmean(settling, later)),
        overshoot_mean=nan_unless_finite(_nanmean(overshoot, later)),
        overshoot_percent_mean=nan_unless_finite(_nanmean(overshoot_percent, later)),
        steady_state_error_mean=nan_unless_finite(_nanmean(steady, later)),
        effort=effort,
        unstable=unstable,
        limit_cycle=cycling,
    )


@partial(jax.jit, static_argnums=0)
def evaluate(spec: closed_loop.LoopSpec, logs: closed_loop.TickLog) -> RunSummary:
    """The summary of every run of a batch of logs (leading axis: the run), in one compiled call;
    the result stays where the logs are (e.g. split over the devices as
    :func:`hsa_core.sim.closed_loop.batch_rollout` left them)."""
    return jax.vmap(run_summary, in_axes=(None, 0))(spec, logs)

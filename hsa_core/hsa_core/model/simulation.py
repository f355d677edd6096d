"""Fixed-step RK4 simulation of the planar HSA robot with zero-order-hold input (model.md §7.1,
§9.4)."""

from typing import Callable

import jax
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from hsa_core.model.dynamics import forward_dynamics_fn
from hsa_core.model.params import HsaParams

DEFAULT_SUBSTEPS = 16
"""Default RK4 steps per held input sample: 16 per 25 ms control period
(benchmarks/bench_model.py)."""

DEFAULT_DT = 0.025 / DEFAULT_SUBSTEPS
"""Default RK4 step, 1.5625 ms: below the stability limit (~3.8 ms, model.md §9.4) and, for a 25 ms
zero-order-hold input sweeping the workspace, within ~0.2 um of a 1e-5 s solution in EE position
over 10 s."""


def rk4(
    q_ddot: Callable[[Array, Array, Array], Array], x: Array, phi: Array, dt: ArrayLike
) -> Array:
    """One classical RK4 step of x_dot = [q_dot, q_ddot(q, q_dot, phi)] with phi held constant."""

    def f(x: Array) -> Array:
        return jnp.concatenate([x[3:], q_ddot(x[:3], x[3:], phi)])

    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rk4_step(params: HsaParams, x: ArrayLike, phi: ArrayLike, dt: ArrayLike) -> Array:
    """One classical RK4 step of length dt of the state x = [q, q_dot] with phi held constant
    (zero-order hold)."""
    return rk4(forward_dynamics_fn(params), _as_f64(x), _as_f64(phi), dt)


def simulate(
    params: HsaParams,
    x0: ArrayLike,
    phi_seq: ArrayLike,
    dt: ArrayLike = DEFAULT_DT,
    substeps: int = DEFAULT_SUBSTEPS,
) -> Array:
    """Roll out phi_seq (N, 2), each sample held for `substeps` RK4 steps of dt; states at hold
    boundaries (N + 1, 6).

    `substeps` must be a Python int (static under jit); dt may be traced. The parameter-only terms
    of the model are computed once, outside the time loop.
    """
    q_ddot = forward_dynamics_fn(params)
    x0 = _as_f64(x0)

    def hold(x: Array, phi: Array) -> tuple[Array, Array]:
        x = jax.lax.fori_loop(0, substeps, lambda _, xk: rk4(q_ddot, xk, phi, dt), x)
        return x, x

    _, xs = jax.lax.scan(hold, x0, _as_f64(phi_seq))
    return jnp.concatenate([x0[None], xs])


def steady_state_rollout(
    params: HsaParams, phi: ArrayLike, duration: float = 5.0, dt: float = 5e-4
) -> Array:
    """Final state [q, q_dot] after holding phi for `duration` s from rest (q = 0, q_dot = 0);
    duration, dt static."""
    q_ddot = forward_dynamics_fn(params)
    phi = _as_f64(phi)
    n_steps = round(duration / dt)
    return jax.lax.fori_loop(0, n_steps, lambda _, x: rk4(q_ddot, x, phi, dt), jnp.zeros(6))


def _as_f64(v: ArrayLike) -> Array:
    """Convert an input to a float64 JAX array."""
    return jnp.asarray(v, dtype=jnp.float64)

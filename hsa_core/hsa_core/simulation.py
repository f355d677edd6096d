"""Fixed-step RK4 simulation of the planar HSA robot with zero-order-hold input (model.md §7.1, §9.4)."""

import jax
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from hsa_core.dynamics import forward_dynamics
from hsa_core.params import HsaParams

DEFAULT_DT = 2.5e-3
"""Default RK4 step [s]; 10 steps per 25 ms control period."""

DEFAULT_SUBSTEPS = 10
"""Default RK4 steps per held input sample."""


def _state_derivative(params: HsaParams, x: Array, phi: Array) -> Array:
    """x_dot = [q_dot, q_ddot] for the state x = [q, q_dot]."""
    q, q_dot = x[:3], x[3:]
    return jnp.concatenate([q_dot, forward_dynamics(params, q, q_dot, phi)])


def rk4_step(params: HsaParams, x: ArrayLike, phi: ArrayLike, dt: ArrayLike) -> Array:
    """One classical RK4 step of length dt with phi held constant (zero-order hold)."""
    x = jnp.asarray(x, dtype=jnp.float64)
    phi = jnp.asarray(phi, dtype=jnp.float64)
    k1 = _state_derivative(params, x, phi)
    k2 = _state_derivative(params, x + 0.5 * dt * k1, phi)
    k3 = _state_derivative(params, x + 0.5 * dt * k2, phi)
    k4 = _state_derivative(params, x + dt * k3, phi)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def simulate(
    params: HsaParams,
    x0: ArrayLike,
    phi_seq: ArrayLike,
    dt: ArrayLike = DEFAULT_DT,
    substeps: int = DEFAULT_SUBSTEPS,
) -> Array:
    """Roll out phi_seq (N, 2), each sample held for `substeps` RK4 steps of dt; states at hold boundaries (N + 1, 6)."""
    x0 = jnp.asarray(x0, dtype=jnp.float64)

    def hold(x: Array, phi: Array) -> tuple[Array, Array]:
        x = jax.lax.fori_loop(0, substeps, lambda _, xk: rk4_step(params, xk, phi, dt), x)
        return x, x

    _, xs = jax.lax.scan(hold, x0, jnp.asarray(phi_seq, dtype=jnp.float64))
    return jnp.concatenate([x0[None], xs])


def steady_state_rollout(params: HsaParams, phi: ArrayLike, duration: float = 5.0, dt: float = 5e-4) -> Array:
    """Final state [q, q_dot] after holding phi for `duration` s from rest (q = 0, q_dot = 0); duration, dt static."""
    n_steps = round(duration / dt)
    phi = jnp.asarray(phi, dtype=jnp.float64)
    return jax.lax.fori_loop(0, n_steps, lambda _, x: rk4_step(params, x, phi, dt), jnp.zeros(6))

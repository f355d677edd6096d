"""Entire functions that remove the 1/kappa singularities of the constant-strain model (model.md §8.2).

Every function switches between a 5-term Taylor series for |x| < X_T and the closed form above it. The closed form is
always evaluated at a safe argument (X_T where the series is selected), so forward- and reverse-mode derivatives stay
finite at x = 0 ("gradient-safe branching").
"""

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

X_T = 0.1
"""Switch-over between series and closed form; series truncation error < 3e-18 below it (model.md §8.2)."""


def _split(x: ArrayLike) -> tuple[Array, Array, Array]:
    """Return (x, small-mask, safe argument) where the safe argument never lets a closed form see |x| < X_T."""
    x = jnp.asarray(x, dtype=jnp.float64)
    small = jnp.abs(x) < X_T
    return x, small, jnp.where(small, X_T, x)


def S(x: ArrayLike) -> Array:
    """sin(x)/x, entire; positions of the CS backbone use sin(kappa s)/kappa = s S(kappa s)."""
    x, small, xs = _split(x)
    x2 = x * x
    series = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)))
    return jnp.where(small, series, jnp.sin(xs) / xs)


def C(x: ArrayLike) -> Array:
    """(1 - cos x)/x^2 in the cancellation-free form 2 sin^2(x/2)/x^2; (1 - cos kappa s)/kappa = s (kappa s) C."""
    x, small, xs = _split(x)
    x2 = x * x
    series = 0.5 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0 * (1.0 - x2 / 56.0 * (1.0 - x2 / 90.0))))
    half_sin = jnp.sin(0.5 * xs)
    return jnp.where(small, series, 2.0 * half_sin * half_sin / (xs * xs))


def T(x: ArrayLike) -> Array:
    """(x - sin x)/x^3, entire; closed-form arc-length integrals, e.g. int_0^l (1 - cos kappa s)/kappa ds = l^2 (kappa l) T."""
    x, small, xs = _split(x)
    x2 = x * x
    series = (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0 * (1.0 - x2 / 110.0)))) / 6.0
    return jnp.where(small, series, (xs - jnp.sin(xs)) / (xs * xs * xs))


def c(theta: ArrayLike) -> Array:
    """(theta/2) cot(theta/2), entire for |theta| < 2 pi; the closed-form IK (model.md §6.3) needs it at theta = 0."""
    theta, small, ts = _split(theta)
    t2 = theta * theta
    series = 1.0 - t2 * (1.0 / 12.0 + t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 / 1209600.0)))
    return jnp.where(small, series, 0.5 * ts / jnp.tan(0.5 * ts))

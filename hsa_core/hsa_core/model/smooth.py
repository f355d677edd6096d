"""Entire functions that remove the 1/kappa singularities of the constant-strain model (model.md
§8.2).

Every function switches between a 5-term Taylor series for |x| < X_T and the closed form above it.
The closed form is always evaluated at a safe argument (X_T where the series is selected), so
forward- and reverse-mode derivatives stay finite at x = 0 ("gradient-safe branching").
"""

import math

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

X_T = 0.1
"""Switch-over between series and closed form; series truncation error < 3e-18 below it (model.md
§8.2)."""


def _split(x: ArrayLike) -> tuple[Array, Array, Array]:
    """Return (x, small-mask, safe argument) where the safe argument never lets a closed form see
    |x| < X_T."""
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
    """(1 - cos x)/x^2 in the cancellation-free form 2 sin^2(x/2)/x^2; (1 - cos kappa s)/kappa = s
    (kappa s) C."""
    x, small, xs = _split(x)
    x2 = x * x
    series = 0.5 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0 * (1.0 - x2 / 56.0 * (1.0 - x2 / 90.0))))
    half_sin = jnp.sin(0.5 * xs)
    return jnp.where(small, series, 2.0 * half_sin * half_sin / (xs * xs))


def T(x: ArrayLike) -> Array:
    """(x - sin x)/x^3, entire; closed-form arc-length integrals, e.g. int_0^l (1 - cos kappa
    s)/kappa ds = l^2 (kappa l) T."""
    x, small, xs = _split(x)
    x2 = x * x
    series = (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0 * (1.0 - x2 / 110.0)))) / 6.0
    return jnp.where(small, series, (xs - jnp.sin(xs)) / (xs * xs * xs))


def c(theta: ArrayLike) -> Array:
    """(theta/2) cot(theta/2), entire for |theta| < 2 pi; the closed-form IK (model.md §6.3) needs
    it at theta = 0."""
    theta, small, ts = _split(theta)
    t2 = theta * theta
    series = 1.0 - t2 * (1.0 / 12.0 + t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 / 1209600.0)))
    return jnp.where(small, series, 0.5 * ts / jnp.tan(0.5 * ts))


def _series_coefficients(
    first_power: int, factorial_offset: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Taylor coefficients (in powers of x^2) of sum_n (-1)^n x^(2n+p) / (2n+p+o)! and of its first
    two derivatives."""
    n = np.arange(_SERIES_TERMS)
    power = 2 * n + first_power
    base = (-1.0) ** n / np.array(
        [math.factorial(int(k)) for k in power + factorial_offset], dtype=float
    )
    return base, base * power, base * power * (power - 1)


_SERIES_TERMS = 7  # x^12 / 13! < 2e-22 at |x| < X_T
_S_SERIES = _series_coefficients(0, 1)  # sin(x)/x = sum (-1)^n x^2n / (2n+1)!
_B_SERIES = _series_coefficients(1, 1)  # (1 - cos x)/x = sum (-1)^n x^(2n+1) / (2n+2)!


def _even_poly(coefficients: np.ndarray, x2: Array) -> Array:
    """sum_n coefficients[n] x^(2n), by Horner's rule in x^2."""
    out = jnp.full_like(x2, coefficients[-1])
    for coefficient in coefficients[-2::-1]:
        out = out * x2 + coefficient
    return out


def arc_terms(x: ArrayLike) -> tuple[Array, ...]:
    """[S, S', S'', B, B', B'', cos x, sin x] at x as eight arrays, with B(x) = x C(x) = (1 - cos
    x)/x.

    E(x) = S(x) + i B(x) = (e^{ix} - 1)/(ix) is the position kernel of the constant-strain backbone
    (model.md §6.1); the dynamics needs it with its first two derivatives at every quadrature node.
    One sin/cos pair (of x/2, so that 1 - cos x = 2 sin^2(x/2) has no cancellation) and one
    reciprocal serve all eight values; below X_T the series of S and B and their termwise
    derivatives are used, with the same gradient-safe branching as S, C, T and c. Eight arrays, not
    one stacked: on the CPU, XLA makes a stack one concatenate kernel that evaluates the shared sin
    and cos (scalar library calls) again for every row, which made the forward dynamics ~5x slower.
    """
    x, small, xs = _split(x)
    half_sin, half_cos = jnp.sin(0.5 * x), jnp.cos(0.5 * x)
    sin, one_minus_cos = 2.0 * half_sin * half_cos, 2.0 * half_sin * half_sin
    cos = 1.0 - one_minus_cos
    inv = 1.0 / xs  # never 1/0: xs = X_T where the series is selected
    S0 = sin * inv
    S1 = (cos - S0) * inv
    S2 = -S0 - 2.0 * S1 * inv
    B0 = one_minus_cos * inv
    B1 = S0 - B0 * inv
    B2 = S1 - (B1 - B0 * inv) * inv
    x2 = x * x
    # odd functions (S', B, B'') carry one factor x; the zero constant terms of S'' and B'' series
    # are dropped
    series = (
        _even_poly(_S_SERIES[0], x2),
        x * _even_poly(_S_SERIES[1][1:], x2),
        _even_poly(_S_SERIES[2][1:], x2),
        x * _even_poly(_B_SERIES[0], x2),
        _even_poly(_B_SERIES[1], x2),
        x * _even_poly(_B_SERIES[2][1:], x2),
    )
    closed = (S0, S1, S2, B0, B1, B2)
    return tuple(jnp.where(small, a, b) for a, b in zip(series, closed)) + (cos, sin)


def arc_functions(x: ArrayLike) -> Array:
    """:func:`arc_terms` stacked, shape (8,) + x.shape."""
    return jnp.stack(arc_terms(x))

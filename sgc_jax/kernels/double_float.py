"""Double-float arithmetic: a value as a float32 pair (hi, lo) with ~44 significant bits, from
error-free transformations (Dekker, Knuth). Built so that a compiler forming multiply-adds (FMA),
as XLA CPU does, cannot break it."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def two_sum(a, b):
    """(s, e) with a + b = s + e exactly (Knuth)."""
    s = a + b
    v = s - a
    return s, (a - (s - v)) + (b - v)


def quick_two_sum(s, e):
    """(t, e') with s + e = t + e' exactly, for |s| >= |e|."""
    t = s + e
    return t, e - (t - s)


def split(a):
    """(hi, lo) with a = hi + lo exactly, each of at most 12 significant bits; by masking mantissa
    bits, which unlike Veltkamp's 4097 a is immune to FMA."""
    hi = jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(a, jnp.int32) & jnp.int32(-4096), jnp.float32)
    return hi, a - hi


def two_prod(a, b):
    """a * b as a double-float, to ~2^-48 relative, from exact products of 12-bit halves only."""
    a_hi, a_lo = split(a)
    b_hi, b_lo = split(b)
    cross, cross_err = two_sum(a_hi * b_lo, a_lo * b_hi)
    p, e = two_sum(a_hi * b_hi, cross)
    return quick_two_sum(p, e + cross_err + a_lo * b_lo)


def df_add(x, y):
    s, e = two_sum(x[0], y[0])
    return quick_two_sum(s, e + x[1] + y[1])


def df_sub(x, y):
    return df_add(x, (-y[0], -y[1]))


def df_mul(x, y):
    p, e = two_prod(x[0], y[0])
    return quick_two_sum(p, e + x[0] * y[1] + x[1] * y[0])


def df_div(x, n):
    """Double-float x divided by a float32 n > 0."""
    q = x[0] / n
    p, e = two_prod(q, n)
    return quick_two_sum(q, ((x[0] - p) - e + x[1]) / n)

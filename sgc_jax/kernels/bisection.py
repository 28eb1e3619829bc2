"""The smallest integer key that reaches a target, by bisection: a few dozen masked counts or sums
over the keys, where XLA CPU's sort of them costs ~10x more. Floats are searched through their
bit patterns, which order as the values do (``ordered_keys``)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

SIGN = 0x80000000


class KeyInterval(NamedTuple):
    """The bisection's state: the key sought lies in [lo, hi]."""

    lo: jax.Array
    hi: jax.Array


def smallest_reaching(reaches: Callable[[jax.Array], jax.Array], lo, hi, steps: int):
    """The smallest key k in [lo, hi] with ``reaches(k)`` (monotone: False below it, True from it
    on), after ``steps`` halvings (ceil(log2(hi - lo + 1)) find it exactly); lo and hi of any
    shape, searched elementwise."""

    def halve(_, interval: KeyInterval) -> KeyInterval:
        mid = interval.lo + (interval.hi - interval.lo) // 2
        enough = reaches(mid)
        return KeyInterval(jnp.where(enough, interval.lo, mid + 1), jnp.where(enough, mid, interval.hi))

    return jax.lax.fori_loop(0, steps, halve, KeyInterval(lo, hi)).lo


def ordered_keys(values):
    """float32 -> uint32 keys in the values' order (negative floats reversed, below the positive ones)."""
    bits = jax.lax.bitcast_convert_type(values.astype(jnp.float32), jnp.uint32)
    sign = jnp.uint32(SIGN)
    return jnp.where(bits & sign, ~bits, bits | sign)


def value_of_key(key):
    """The float32 whose ``ordered_keys`` key is ``key``."""
    sign = jnp.uint32(SIGN)
    return jax.lax.bitcast_convert_type(jnp.where(key & sign, key ^ sign, ~key), jnp.float32)

"""Fences against XLA CPU's fusion of producers into their consumers (``materialise``,
``gather_apart``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def materialise(tree):
    """``tree`` unchanged, but computed once into memory: XLA CPU otherwise fuses an expensive
    elementwise producer into each of its consumers and recomputes it per output element
    (``optimization_barrier`` is dropped before fusion there). A loop XLA cannot unroll or
    hoist, run once (an identity: it multiplies by 1), is the fence. The first leaf's first entry
    must be finite (an inf there makes the factor NaN): put an integer leaf first where a float
    one may not be."""
    leaves = jax.tree_util.tree_leaves(tree)
    first = leaves[0].reshape(-1)[0]
    trips = (first != first).astype(jnp.int32) + 1  # 1 (2 for a NaN), which XLA cannot bound to 1
    unit = 1.0 + 0.0 * first  # 1 (NaN for a NaN), which XLA cannot fold

    def body(carry):
        i, scale, value = carry
        return i + 1, scale, jax.tree.map(lambda x: x * scale.astype(x.dtype), value)

    _, _, out = jax.lax.while_loop(lambda c: c[0] < trips, body, (jnp.int32(0), unit, tree))
    return out


def gather_apart(values, index):
    """``values[index]`` as a gather of its own: XLA CPU fuses the producers of a gather's operand
    and indices into it and runs them once per gathered element, unvectorised. A conditional's
    branch is a computation of its own, so both branches gather; under ``vmap`` the predicate is
    batched and the two equal gathers merge into one plain gather. ``index`` must not be empty."""
    gather = lambda: values[index]  # noqa: E731
    return jax.lax.cond(index.reshape(-1)[0] < 0, gather, gather)

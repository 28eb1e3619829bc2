"""``kernels.fence``: the fences against XLA CPU's fusion change how a value is computed, never
the value: ``gather_apart`` is ``values[index]`` bit for bit, alone, jitted, vmapped and
differentiated, and under ``vmap`` it compiles to a plain gather; ``materialise`` returns its
tree unchanged."""

import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax.kernels.fence import gather_apart, materialise

RNG = np.random.default_rng(0)
VALUES = jnp.asarray(RNG.standard_normal((3, 50)), jnp.float32)
INDEX = jnp.asarray(RNG.integers(0, 50, (3, 40)), jnp.int32)


def test_gather_apart_is_the_plain_gather():
    plain = VALUES[0][INDEX[0]]
    np.testing.assert_array_equal(gather_apart(VALUES[0], INDEX[0]), plain)
    np.testing.assert_array_equal(jax.jit(gather_apart)(VALUES[0], INDEX[0]), plain)
    np.testing.assert_array_equal(jax.jit(jax.vmap(gather_apart))(VALUES, INDEX), jax.vmap(lambda v, i: v[i])(VALUES, INDEX))


def test_gather_apart_passes_gradients_as_the_gather():
    weights = jnp.arange(40, dtype=jnp.float32)
    apart = jax.grad(lambda v: jnp.sum(weights * gather_apart(v, INDEX[0])))(VALUES[0])
    plain = jax.grad(lambda v: jnp.sum(weights * v[INDEX[0]]))(VALUES[0])
    np.testing.assert_array_equal(apart, plain)


def test_gather_apart_under_vmap_compiles_to_one_plain_gather():
    hlo = jax.jit(jax.vmap(gather_apart)).lower(VALUES, INDEX).compile().as_text()
    assert "conditional(" not in hlo
    assert hlo.count(" gather(") == 1


def test_materialise_returns_its_tree_unchanged():
    tree = (INDEX, {"values": VALUES, "mask": VALUES > 0})
    out = jax.jit(materialise)(tree)
    for got, want in zip(jax.tree.leaves(out), jax.tree.leaves(tree)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)

"""A while loop whose vmapped form leaves its finished lanes behind (docs/semantics.md §9.3).

``jax.lax.while_loop`` under ``vmap`` runs its body on every lane until the slowest is done, the
finished ones carried along. ``while_loop_by_lane`` runs every lane at once while more than one in
NARROW_SHARE is still running, then gathers those into a batch that narrow and runs them to their
end. Each lane takes the same steps on the same values as alone; what changes is only how many
finished lanes ride along. The lanes are every vmapped axis around the call at once (nested
vmaps flattened), so an accelerator's one wide program, its clips, pairs and regions, is one batch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

# The narrow phase holds one lane in NARROW_SHARE; below MIN_LANES lanes (the default) every lane
# runs to the end (the gather and a second copy of the body cost more than so few lanes save).
NARROW_SHARE = 8
MIN_LANES = 256


def while_loop_by_lane(cond_fun, body_fun, init_val, consts, *, min_lanes: int | None = None):
    """``jax.lax.while_loop(lambda s: cond_fun(s, consts), lambda s: body_fun(s, consts), init_val)``;
    under ``vmap`` the finished lanes are left behind (module docstring). ``consts``: every array the
    two functions read (a pytree); they must not close over traced values. ``min_lanes`` (default
    MIN_LANES): fewer lanes all run to the end."""
    min_lanes = MIN_LANES if min_lanes is None else min_lanes

    def plain(state, consts):
        return jax.lax.while_loop(lambda s: cond_fun(s, consts), lambda s: body_fun(s, consts), state)

    def run_lanes(states, consts):  # a leading lane axis on every leaf
        return _run_lanes(cond_fun, body_fun, states, consts, min_lanes)

    by_lanes = custom_vmap(run_lanes)

    @by_lanes.def_vmap
    def flatten_lanes(axis_size, in_batched, states, consts):  # an outer vmap: its lanes join the batch
        states, consts = _broadcast(states, in_batched[0], axis_size), _broadcast(consts, in_batched[1], axis_size)
        out = by_lanes(*(jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), tree) for tree in (states, consts)))
        return (jax.tree.map(lambda x: x.reshape((axis_size, -1) + x.shape[1:]), out),
                jax.tree.map(lambda _: True, out))

    one_lane = custom_vmap(plain)

    @one_lane.def_vmap
    def as_lanes(axis_size, in_batched, state, consts):
        out = by_lanes(_broadcast(state, in_batched[0], axis_size), _broadcast(consts, in_batched[1], axis_size))
        return out, jax.tree.map(lambda _: True, out)

    return one_lane(init_val, consts)


def _broadcast(tree, batched, n: int):
    return jax.tree.map(lambda x, b: x if b else jnp.broadcast_to(x, (n,) + jnp.shape(x)), tree, batched)


def _run_lanes(cond_fun, body_fun, states, consts, min_lanes: int):
    """Every lane (leading axis L of ``states`` and ``consts``) stepped until its cond_fun is False."""
    lanes = jax.tree.leaves(states)[0].shape[0]
    running_of = jax.vmap(cond_fun)
    step_all = jax.vmap(body_fun)

    def advance(carry, consts):
        states, running = carry
        moved = step_all(states, consts)
        states = jax.tree.map(lambda new, old: jnp.where(running.reshape((-1,) + (1,) * (new.ndim - 1)), new, old),
                              moved, states)
        return states, running & running_of(states, consts)

    carry = (states, running_of(states, consts))
    narrow = lanes // NARROW_SHARE
    if lanes < min_lanes or narrow < 1:
        return jax.lax.while_loop(lambda c: jnp.any(c[1]), lambda c: advance(c, consts), carry)[0]

    states, running = jax.lax.while_loop(lambda c: jnp.sum(c[1], dtype=jnp.int32) > narrow,
                                         lambda c: advance(c, consts), carry)
    lane = jnp.nonzero(running, size=narrow, fill_value=lanes)[0]  # the running lanes, then none
    taken = jnp.minimum(lane, lanes - 1)
    few_states, few_consts = (jax.tree.map(lambda x: x[taken], tree) for tree in (states, consts))
    few_states = jax.lax.while_loop(lambda c: jnp.any(c[1]), lambda c: advance(c, few_consts),
                                    (few_states, lane < lanes))[0]
    return jax.tree.map(lambda x, few: x.at[lane].set(few, mode="drop"), states, few_states)

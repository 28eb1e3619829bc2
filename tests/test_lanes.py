"""``kernels.lanes.while_loop_by_lane``: under vmap each lane takes the same steps on the same
values as alone (docs/semantics.md §9.3), and a batch whose lanes are nearly all done leaves them
behind."""

import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax.kernels import lanes
from sgc_jax.kernels.lanes import while_loop_by_lane


def _running(state, consts):
    return state["steps"] < consts["length"]


def _step(state, consts):
    # float work whose rounding would show a lane stepped on other values
    return {"steps": state["steps"] + 1, "x": state["x"] * consts["gain"] + jnp.sin(state["x"])}


def _by_lane(length, gain, x0):
    return while_loop_by_lane(_running, _step, {"steps": jnp.int32(0), "x": x0}, {"length": length, "gain": gain})


def _alone(length, gain, x0):
    consts = {"length": length, "gain": gain}
    return jax.lax.while_loop(lambda s: _running(s, consts), lambda s: _step(s, consts),
                              {"steps": jnp.int32(0), "x": x0})


def _lanes(shape, seed=0):
    """Lengths as RANSAC's draws have them: most lanes short, a few at the cap."""
    rng = np.random.default_rng(seed)
    length = rng.choice([2] * 28 + [3, 4, 6, 10], size=shape).astype(np.int32)
    return jnp.asarray(length), jnp.asarray(rng.normal(size=shape + (3,)).astype(np.float32))


def _nested(fn):
    """fn vmapped over clips, pairs and regions, the start x0 shared (unbatched)."""
    for _ in range(3):
        fn = jax.vmap(fn, in_axes=(0, 0, None))
    return jax.jit(fn)


def test_each_lane_takes_its_own_steps_bit_for_bit_under_nested_vmaps():
    length, gain = _lanes((4, 15, 10))  # 600 lanes: every lane at once, then the narrow phase
    x0 = jnp.linspace(0.1, 0.3, 3)
    got, want = _nested(_by_lane)(length, gain, x0), _nested(_alone)(length, gain, x0)
    np.testing.assert_array_equal(got["steps"], length)
    for leaf in ("steps", "x"):
        np.testing.assert_array_equal(got[leaf], want[leaf])


def test_fewer_lanes_than_min_lanes_run_alike_and_one_lane_is_the_plain_loop():
    length, gain = _lanes((12,), seed=1)
    x0 = jnp.ones(3)
    got = jax.jit(jax.vmap(_by_lane, in_axes=(0, 0, None)))(length, gain, x0)
    want = jax.jit(jax.vmap(_alone, in_axes=(0, 0, None)))(length, gain, x0)
    np.testing.assert_array_equal(got["x"], want["x"])
    one = jax.jit(_by_lane)(length[0], gain[0], x0)
    np.testing.assert_array_equal(one["x"], jax.jit(_alone)(length[0], gain[0], x0)["x"])


def test_finished_lanes_leave_the_batch():
    length, gain = _lanes((lanes.MIN_LANES * 2,), seed=2)
    executed = []

    def counted_step(state, consts):
        jax.debug.callback(lambda steps: executed.append(1), state["steps"])  # once per lane and step
        return _step(state, consts)

    def by_lane(length, gain):
        return while_loop_by_lane(_running, counted_step, {"steps": jnp.int32(0), "x": jnp.ones(3)},
                                  {"length": length, "gain": gain})

    jax.block_until_ready(jax.jit(jax.vmap(by_lane))(length, gain))
    # every lane while more than one in NARROW_SHARE runs, then a batch of that many to the end
    n, narrow = length.size, length.size // lanes.NARROW_SHARE
    wide = next(i for i in range(int(length.max()) + 1) if int(np.sum(np.asarray(length) > i)) <= narrow)
    assert len(executed) == wide * n + (int(length.max()) - wide) * narrow
    assert len(executed) < 0.5 * int(length.max()) * n  # against every lane run to the slowest's end

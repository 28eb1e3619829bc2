"""How much of the pose search's loop work the vectorized (accelerator) form spends waiting for its
slowest lane (issue 61, item 2), measured on any machine.

    python bench/lane_work.py [--clips 16] [--group 5]

Scores --clips standard clips (bench/stream.py's corpus, distinct scenes) in one call of the
Scorer's vectorized programs, as an accelerator runs `score_batch`'s group of 16: every pair of
every clip is a lane of one vmapped program. While the pose program is traced, each of three loops
counts its iterations per lane and hands the counts to the host after it ends (a host callback,
so the compilation cache is off: such programs cannot be exported):

- `region_start`: RANSAC's draws, chunks of minimal samples (a lane: one region of one pair);
- `local_optima`: the local search's refits (a lane: one pair);
- `solve_pnp_regions`: the Levenberg-Marquardt steps of each refit (a lane: one pair).

A vmapped while loop runs until its slowest lane is done; a lane that is done is carried along.
Printed per loop: each invocation's largest and mean count, and the lane-iterations executed with
every lane at once, in groups of --group consecutive lanes (the CPU's form: PAIRS_AT_ONCE pairs,
their regions; derived from the same counts, an upper bound: a CPU group whose pairs have all
finished their refits skips what the batch runs here), and what the lanes need alone. What leaving finished lanes out could save is the
difference, if a step's time follows the lanes it holds (`bench/gpu_figures.sh widths` measures
that on a GPU). RANSAC's draws and the least-squares solves leave their finished lanes behind
(`kernels/lanes.py`): for them the lane-iterations the program executed are counted too, each of
its loops' iterations times the lanes it holds. The counts do not depend on the machine.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
from pathlib import Path

os.environ["SGC_JAX_COMPILATION_CACHE"] = "off"  # programs with host callbacks are not exported

HERE = Path(__file__).resolve().parent
LOOPS = {"region_start": "region", "local_optima": "pair", "solve_pnp_regions": "pair"}


def counting_while_loop(while_loop, counts: dict[str, list[int]], executed: dict[str, list[int]]):
    """``jax.lax.while_loop`` that, in LOOPS' functions, also counts its iterations per lane and
    appends each lane's count to counts[function] after the loop (one host call per lane, in
    order, under vmap); called from ``kernels.lanes._run_lanes`` (lanes explicit), it appends its
    iterations times the lanes it holds to executed[its loop] (named by ``counting_lane_loop``)."""
    import jax

    def loop(cond_fun, body_fun, init_val):
        caller = sys._getframe(1).f_code.co_name
        if caller not in LOOPS and caller != "_run_lanes":
            return while_loop(cond_fun, body_fun, init_val)
        final, n = while_loop(lambda c: cond_fun(c[0]), lambda c: (body_fun(c[0]), c[1] + 1), (init_val, 0))
        if caller == "_run_lanes":
            width = jax.tree.leaves(init_val)[0].shape[0]
            name = sys._getframe(1).f_locals["cond_fun"].lane_loop
            jax.debug.callback(lambda m: executed[name].append(int(m) * width), n)
        else:
            jax.debug.callback(lambda m: counts[caller].append(int(m)), n)
        return final

    return loop


def counting_lane_loop(lane_loop, name: str, counts: list[int]):
    """``kernels.lanes.while_loop_by_lane`` called in function ``name`` that also counts each
    lane's iterations (appended to ``counts`` after the loop, one host call per lane)."""
    import jax

    def loop(cond_fun, body_fun, init_val, consts, **options):
        def cond(c, x):
            return cond_fun(c[0], x)

        cond.lane_loop = name
        final, n = lane_loop(cond, lambda c, x: (body_fun(c[0], x), c[1] + 1), (init_val, jax.numpy.int32(0)),
                             consts, **options)
        jax.debug.callback(lambda m: counts.append(int(m)), n)
        return final

    return loop


def lane_iterations(counts: list[int], lanes: int, group: int) -> tuple[int, int, int, list[int], list[float]]:
    """(alone, in groups of ``group``, all at once, each invocation's largest, its mean) for an
    invocation's ``lanes`` consecutive counts."""
    import numpy as np

    per_invocation = np.asarray(counts).reshape(-1, lanes)
    grouped = per_invocation.reshape(len(per_invocation), -1, group).max(-1).sum(-1) * group
    return (int(per_invocation.sum()), int(grouped.sum()), int(per_invocation.max(-1).sum() * lanes),
            per_invocation.max(-1).tolist(), per_invocation.mean(-1).round(2).tolist())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=16, help="clips in the one call (an accelerator's group: 16)")
    parser.add_argument("--group", type=int, default=5, help="consecutive pairs vmapped together in the CPU's form")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE.parent))
    sys.path.insert(0, str(HERE))
    import jax
    from stream import SCENE, host_cpu

    import sgc_jax.kernels.joint_pnp as joint_pnp_module
    import sgc_jax.kernels.ransac as ransac_module
    import sgc_jax.scoring.scorer as scorer_module
    from sgc_jax import Scorer, SGCConfig
    from sgc_jax.research.synth import synth_clip
    from sgc_jax.scoring.scorer import batch_of

    counts: dict[str, list[int]] = collections.defaultdict(list)
    executed: dict[str, list[int]] = collections.defaultdict(list)
    jax.lax.while_loop = counting_while_loop(jax.lax.while_loop, counts, executed)
    for module, name in ((ransac_module, "region_start"), (joint_pnp_module, "solve_pnp_regions")):
        module.while_loop_by_lane = counting_lane_loop(module.while_loop_by_lane, name, counts[name])
    scorer_module.default_lanes = lambda devices: 1  # one program call holds every clip, as on an accelerator
    clips = [synth_clip(seed=i, **SCENE) for i in range(args.clips)]
    shape = (SCENE["n_frames"], SCENE["height"], SCENE["width"], SCENE["n_tracks"])
    scorer = Scorer((args.clips, *shape), vectorized=True)
    jax.block_until_ready(scorer(jax.device_put(batch_of(clips, shape))))

    pairs = args.clips * (SCENE["n_frames"] - 1)
    lanes = {"pair": pairs, "region": pairs * SGCConfig().k_seg}
    print(f"{host_cpu()}; {args.clips} standard clips in one vectorized call: {pairs} pairs, "
          f"{lanes['region']} regions")
    print("| loop | lanes | invocations: largest count (mean) | lane-iterations: alone | "
          f"in groups of {args.group} | all at once | executed |")
    print("|---|---|---|---|---|---|---|")
    for name, lane in LOOPS.items():
        n_lanes = lanes[lane]
        group = args.group * (n_lanes // pairs)  # the CPU groups pairs, with all their regions
        alone, grouped, at_once, largest, mean = lane_iterations(counts[name], n_lanes, group)
        invocations = ", ".join(f"{m} ({a})" for m, a in zip(largest, mean))
        ran = sum(executed[name]) if name in executed else at_once  # the others: every lane to the end
        print(f"| `{name}` | {n_lanes} {lane}s | {invocations} | {alone} | {grouped} ({grouped / alone:.2f}x) | "
              f"{at_once} ({at_once / alone:.2f}x) | {ran} ({ran / alone:.2f}x) |")


if __name__ == "__main__":
    main()

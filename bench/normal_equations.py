"""Forms of the least-squares step's normal equations (issue 61, item 1), timed on any device.

    python bench/normal_equations.py [--pairs 960] [--points 4096] [--regions 10] [--repeats 20]

Each form computes what ``joint_pnp.linearise`` returns (every region's squared error, J^T J and
J^T r) for --pairs pairs at once (64 standard clips x 15 pairs by default), vmapped as the
Scorer's accelerator form does. Printed per form: ms per call (median of --repeats), the largest
difference from the package's form relative to its size, and the same for one whole
``solve_pnp_regions`` (Levenberg-Marquardt, at most 10 steps) with the form in its place.

- ``package``: ``joint_pnp.linearise`` on every platform since 2026-12-04: the 28 values a slot adds
  (J^T J's 21 distinct products, J^T r's 6, the cost) summed within chunks by one reduction of 28
  operands (``jax.lax.reduce``), whose loop makes each slot's J once for all 28; then one
  chunk-to-region product (measured as ``variadic``, then ``cpu-form``, before it became the package's)
- ``stacked-unfenced``: the accelerator's form before that: the 28 values stacked (28, n_chunks,
  SLOT_CHUNK) and summed within chunks by one reduction that makes J where it reads it, again for
  each of the 28 rows
- ``fenced``: the CPU's form before that: J fenced into memory, all products from one broadcast
  summed within each 32-slot chunk, then the chunk-to-region product; cost and J^T r by ``block_sums``
- ``unfenced``: ``fenced`` without the fence, so XLA may fuse J into its consumers
- ``chunk-dot``: per-chunk J_c J_c^T as a batched dot over chunks, then chunk-to-region
- ``augmented``: A = (J; r), 7 rows per image axis, one batched dot per axis gives J^T J, J^T r
  and r^T r at once
- ``stacked``, ``stacked-last``: ``stacked-unfenced`` with J fenced into memory, and with the 28
  values on the last axis
- ``siblings``: the 28 values summed within chunks by 28 reductions side by side (XLA may fuse
  them into one kernel, as ``package``'s one reduction is by construction)
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from sgc_jax.kernels import joint_pnp
from sgc_jax.kernels.fence import materialise
from sgc_jax.kernels.regions import block_normals, block_sums
from sgc_jax.kernels.so3 import so3_exp

HIGHEST = jax.lax.Precision.HIGHEST
PACKAGE_LINEARISE = joint_pnp.linearise


def jacobians(problem, R, t, fence: bool):
    """(du, dv) and scaled (J_u, J_v), each (6, n_chunks, SLOT_CHUNK), as ``linearise`` makes them."""
    residuals, J = joint_pnp.scaled_jacobians(problem, R, t)
    return residuals, materialise(J) if fence else J


def block_products(problem, R, t, fence: bool):
    onehot = problem.slots.chunk_onehot
    (du, dv), (J_u, J_v) = jacobians(problem, R, t, fence)
    cost = block_sums(onehot, (du * du + dv * dv)[None])[:, 0]
    return joint_pnp.Linearisation(cost, block_normals(onehot, J_u, J_v), block_sums(onehot, J_u * du + J_v * dv))


def chunk_dot(problem, R, t):
    onehot = problem.slots.chunk_onehot
    (du, dv), (J_u, J_v) = jacobians(problem, R, t, fence=False)
    gram = (jnp.einsum("icp,jcp->cij", J_u, J_u, precision=HIGHEST)
            + jnp.einsum("icp,jcp->cij", J_v, J_v, precision=HIGHEST))
    cost = block_sums(onehot, (du * du + dv * dv)[None])[:, 0]
    normal = jnp.einsum("kc,cij->kij", onehot, gram, precision=HIGHEST)
    return joint_pnp.Linearisation(cost, normal, block_sums(onehot, J_u * du + J_v * dv))


def augmented(problem, R, t):
    onehot = problem.slots.chunk_onehot
    (du, dv), (J_u, J_v) = jacobians(problem, R, t, fence=False)
    A_u = jnp.concatenate([J_u, du[None]])  # (7, n_chunks, SLOT_CHUNK)
    A_v = jnp.concatenate([J_v, dv[None]])
    gram = (jnp.einsum("icp,jcp->cij", A_u, A_u, precision=HIGHEST)
            + jnp.einsum("icp,jcp->cij", A_v, A_v, precision=HIGHEST))
    G = jnp.einsum("kc,cij->kij", onehot, gram, precision=HIGHEST)  # (k, 7, 7)
    return joint_pnp.Linearisation(G[:, 6, 6], G[:, :6, :6], G[:, :6, 6])


def stacked_sums(problem, R, t, fence: bool, products_last: bool):
    """J^T J's 21 distinct products, J^T r's 6 and r^T r stacked into one array (28 values a slot),
    summed within chunks by one reduction, then one chunk-to-region product."""
    (du, dv), (J_u, J_v) = jacobians(problem, R, t, fence)
    values = joint_pnp.slot_values(du, dv, J_u, J_v)
    if products_last:
        sums = jnp.sum(jnp.stack(values, -1), axis=1).T  # (n_chunks, SLOT_CHUNK, 28) -> (28, n_chunks)
    else:
        sums = jnp.sum(jnp.stack(values), axis=-1)  # (28, n_chunks, SLOT_CHUNK) -> (28, n_chunks)
    return joint_pnp.per_region(problem, sums)


def siblings(problem, R, t):
    """28 reductions side by side, one per value, for XLA to fuse as siblings that share J's making."""
    (du, dv), (J_u, J_v) = jacobians(problem, R, t, fence=False)
    values = joint_pnp.slot_values(du, dv, J_u, J_v)
    return joint_pnp.per_region(problem, jnp.stack([jnp.sum(v, axis=-1) for v in values]))


FORMS = {"package": PACKAGE_LINEARISE,
         "stacked-unfenced": lambda p, R, t: stacked_sums(p, R, t, fence=False, products_last=False),
         "fenced": lambda p, R, t: block_products(p, R, t, fence=True),
         "unfenced": lambda p, R, t: block_products(p, R, t, fence=False), "chunk-dot": chunk_dot,
         "augmented": augmented,
         "stacked": lambda p, R, t: stacked_sums(p, R, t, fence=True, products_last=False),
         "stacked-last": lambda p, R, t: stacked_sums(p, R, t, fence=True, products_last=True),
         "siblings": siblings}


def pairs_of(key, P: int, N: int, k: int):
    """P pairs of N points in k regions: X (P, N, 3) in front of the camera, their pixels under a
    small motion with 0.5 px noise, unit weights, regions in contiguous runs, starts at identity."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    K = jnp.array([[400.0, 0.0, 256.0], [0.0, 400.0, 144.0], [0.0, 0.0, 1.0]])
    xy = jax.random.uniform(k1, (P, N, 2), minval=-1.5, maxval=1.5)
    z = jax.random.uniform(k2, (P, N, 1), minval=2.0, maxval=8.0)
    X = jnp.concatenate([xy * z / 3.0, z], -1)
    motion = 0.02 * jax.random.normal(k3, (P, 6))
    Y = jnp.einsum("pij,pnj->pni", jax.vmap(so3_exp)(motion[:, :3]), X) + motion[:, None, 3:]
    uv = (Y[..., :2] / Y[..., 2:]) * 400.0 + jnp.array([256.0, 144.0])
    uv = uv + 0.5 * jax.random.normal(k4, uv.shape)
    region = jnp.broadcast_to((jnp.arange(N) * k // N + 1).astype(jnp.int32), (P, N))
    weight = jnp.ones((P, N))
    return X, uv, weight, region, K, jnp.zeros((P, k, 6))


def timed(fn, args, repeats: int):
    jax.block_until_ready(fn(*args))  # compile
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - begin)
    return 1000 * statistics.median(times)


def relative_difference(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-30))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=960)
    parser.add_argument("--points", type=int, default=4096)
    parser.add_argument("--regions", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--forms", nargs="+", choices=sorted(FORMS), default=list(FORMS))
    args = parser.parse_args()
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}); {args.pairs} pairs of "
          f"{args.points} points in {args.regions} regions", flush=True)
    X, uv, weight, region, K, pose0 = pairs_of(jax.random.key(0), args.pairs, args.points, args.regions)
    k = args.regions
    problems = jax.jit(jax.vmap(lambda X, uv, w, r: joint_pnp.problem_of(X, uv, w, r, K, k)))(X, uv, weight, region)
    R = jnp.broadcast_to(jnp.eye(3), (args.pairs, k, 3, 3))
    t = jnp.zeros((args.pairs, k, 3))
    reference = solved_reference = None
    print("| form | linearise ms | rel. diff. | LM solve ms | rel. diff. of the poses |")
    print("|---|---|---|---|---|", flush=True)
    for name in ["package"] + [f for f in args.forms if f != "package"]:
        form = FORMS[name]
        linearise = jax.jit(jax.vmap(form))
        ms = timed(linearise, (problems, R, t), args.repeats)
        out = linearise(problems, R, t)
        joint_pnp.linearise = form  # traced into the solve below
        solve = jax.jit(jax.vmap(lambda X, uv, w, r, p: joint_pnp.solve_pnp_regions(X, uv, w, r, K, p, steps=10)[0]))
        solve_ms = timed(solve, (X, uv, weight, region, pose0), max(3, args.repeats // 4))
        poses = solve(X, uv, weight, region, pose0)
        joint_pnp.linearise = PACKAGE_LINEARISE
        if reference is None:
            reference, solved_reference = out, poses
        diff = max(relative_difference(a, b) for a, b in zip(out, reference))
        print(f"| {name} | {ms:.3f} | {diff:.1e} | {solve_ms:.2f} | {relative_difference(poses, solved_reference):.1e} |",
              flush=True)


if __name__ == "__main__":
    main()

"""Least-squares poses with gradients from their optimality condition (docs/semantics.md §10.2):
the pose minimising a fixed point set's squared reprojection error, differentiated by the
implicit function theorem at the optimum, never through the solver's iterations. Poses and pixels
as in ``pnp``."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .pnp import reprojection_residuals

# Newton steps from the forward pass's pose in float64 (gradient checks), where the exact optimum
# is wanted: the forward pose is the optimum to the Levenberg-Marquardt tolerance (within ~0.01 deg,
# bench/history/issue-42.md, "Gradients of SGC"), and quadratic convergence takes it to float64's in three. In float32 none:
# the forward pose stands, so that sgc_smooth equals sgc.
POLISH_STEPS = 3


def squared_error_gradient(pose6, X, uv, K, weight):
    """d/d pose6 of half the weighted squared reprojection error (6,)."""
    return jax.grad(lambda p: 0.5 * jnp.sum(reprojection_residuals(p, X, uv, K, weight) ** 2))(pose6)


def least_squares_pose(pose0, X, uv, K, weight, solved, steps: int | None = None):
    """The pose (6,) minimising sum weight |project(R X + t) - uv|^2 at pose0 (6,), the optimum
    found by the forward pass (``steps`` Newton steps from it: default POLISH_STEPS in float64, 0
    in float32), differentiable with respect to X (N, 3), uv (N, 2) and K (3, 3) through the
    optimality condition. ``weight`` (N,) is held fixed; where ``solved`` is False (no pose to
    differentiate) the result is pose0 with zero gradient."""
    if steps is None:
        steps = POLISH_STEPS if X.dtype == jnp.float64 else 0
    weight = jax.lax.stop_gradient(jnp.where(solved, weight, 0.0))
    anchor = jax.lax.stop_gradient(pose0)

    def condition(pose):  # zero at the optimum; pose - pose0 where there is none, so it stays regular
        return jnp.where(solved, squared_error_gradient(pose, X, uv, K, weight), pose - anchor)

    def newton(f, start):
        def step(_, pose):
            moved = pose - jnp.linalg.solve(jax.jacfwd(f)(pose), f(pose))
            return jnp.where(jnp.all(jnp.isfinite(moved)), moved, pose)

        return jax.lax.fori_loop(0, steps, step, start)

    def tangent_solve(linear, y):  # the Hessian is 6 x 6: form it and solve
        return jnp.linalg.solve(jax.jacfwd(linear)(y), y)

    return jax.lax.custom_root(condition, anchor, newton, tangent_solve)

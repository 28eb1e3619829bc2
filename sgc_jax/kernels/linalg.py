"""Small dense linear algebra unrolled into elementwise operations, which fuse under ``vmap`` on
CPU where XLA's batched tiny matmuls and LAPACK calls cost more than the arithmetic."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx


def small_matmul(A, B):
    """A (..., m, k) @ B (..., k, n), unrolled over k (3x3 work inside ``vmap``)."""
    return sum(A[..., :, k, None] * B[..., None, k, :] for k in range(A.shape[-1]))


def solve_spd(A, b):
    """x (n,) solving A x = b for a small symmetric positive (semi)definite A (n, n), b (n,).

    Unrolled Cholesky; pivots floored at 1e-7 trace(A) / n, so a singular direction gets a zero
    step instead of NaN."""
    n = A.shape[-1]
    floor = 1e-7 * jnp.trace(A) / n + jnp.finfo(A.dtype).tiny
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        d = jnp.sqrt(jnp.maximum(A[j, j] - sum(L[j][k] ** 2 for k in range(j)), floor))
        L[j][j] = d
        for i in range(j + 1, n):
            L[i][j] = (A[i, j] - sum(L[i][k] * L[j][k] for k in range(j))) / d
    y = [None] * n
    for i in range(n):
        y[i] = (b[i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(L[k][i] * x[k] for k in range(i + 1, n))) / L[i][i]
    return jnp.stack(x)


# Jacobian rows from which NormalCholesky forms J^T J with a matmul (fewer: fused elementwise sums)
DOT_MIN_ROWS = 64


class NormalCholesky(lx.AbstractLinearSolver):
    """lineax solver of a tall real J by J^T J x = J^T b with ``solve_spd``, for the 6-parameter
    pose solves inside ``vmap``; the operator's input must be one array. Its transpose (a
    minimum-norm solve J (J^T J)^-1 b) lets lineax differentiate through it."""

    def init(self, operator, options):
        del options
        return operator.as_matrix(), operator.in_structure(), operator.out_structure(), False

    def compute(self, state, vector, options):
        del options
        J, in_structure, out_structure, transposed = state
        b = jnp.concatenate([leaf.reshape(-1) for leaf in jax.tree_util.tree_leaves(vector)])
        if J.shape[0] > DOT_MIN_ROWS:  # XLA CPU reduces many J_i J_i^T slowly; one matmul
            normal = jnp.einsum("ni,nj->ij", J, J, precision=jax.lax.Precision.HIGHEST)
        else:
            normal = jnp.sum(J[:, :, None] * J[:, None, :], axis=0)
        if transposed:
            x, structure = J @ solve_spd(normal, b), out_structure
        else:  # J^T b by elementwise sums: XLA CPU's matrix-vector dot costs more at any size
            x, structure = solve_spd(normal, jnp.sum(J * b[:, None], axis=0)), in_structure
        return x.reshape(structure.shape).astype(structure.dtype), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        J, in_structure, out_structure, transposed = state
        return (J, in_structure, out_structure, not transposed), options

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True

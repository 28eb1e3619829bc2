"""The small normal-equations least-squares solver used by Gauss-Newton PnP."""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np

from sgc_jax.kernels.linalg import NormalCholesky


def test_solve_and_transposed_solve_match_the_pseudo_inverse():
    J = np.random.default_rng(0).normal(size=(10, 6)).astype(np.float32)
    b, c = np.arange(10, dtype=np.float32), np.arange(6, dtype=np.float32)
    operator = lx.MatrixLinearOperator(jnp.asarray(J))
    solver = NormalCholesky()
    state = solver.init(operator, {})
    x, result, _ = solver.compute(state, jnp.asarray(b), {})
    np.testing.assert_allclose(x, np.linalg.pinv(J) @ b, rtol=1e-3, atol=1e-4)
    t_state, t_options = solver.transpose(state, {})
    y, _, _ = solver.compute(t_state, jnp.asarray(c), t_options)
    np.testing.assert_allclose(y, np.linalg.pinv(J).T @ c, rtol=1e-3, atol=1e-4)
    assert solver.conj(state, {})[0] is state


def test_gradient_through_linear_solve_is_finite():
    J = jnp.asarray(np.random.default_rng(1).normal(size=(8, 6)), jnp.float32)

    def loss(b):
        return jnp.sum(lx.linear_solve(lx.MatrixLinearOperator(J), b, NormalCholesky()).value ** 2)

    grad = jax.grad(loss)(jnp.ones(8, jnp.float32))
    assert np.isfinite(np.asarray(grad)).all()

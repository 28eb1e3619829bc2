"""sgc_jax.kernels.so3 and camera: SO(3) exp/log, stable rotation angles, nearest rotation, pinhole projection.

float32 (the production path) throughout; float64 NumPy is the reference.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from sgc_jax.kernels.camera import back_project, project_floored
from sgc_jax.kernels.so3 import nearest_rotation, rotation_angle_deg, so3_exp, so3_log

# float32 tolerances: entries of R carry ~1e-7 rounding; the log near pi loses ~sqrt of that
# in the axis direction, hence the looser near-pi bound.
ROUND_TRIP_ATOL = 2e-6
NEAR_PI_ATOL = 5e-4

exp_log = jax.jit(lambda w: so3_log(so3_exp(w)))
angle_deg = jax.jit(rotation_angle_deg)


def rotvec(axis, angle_rad):
    axis = np.asarray(axis, np.float64)
    return axis / np.linalg.norm(axis) * angle_rad


def rodrigues64(w):
    w = np.asarray(w, np.float64)
    theta = np.linalg.norm(w)
    if theta == 0:
        return np.eye(3)
    k = w / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def angle64_deg(R_a, R_b):
    M = np.asarray(R_a, np.float64).T @ np.asarray(R_b, np.float64)
    s = 0.5 * np.linalg.norm([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    return np.degrees(np.arctan2(s, 0.5 * (np.trace(M) - 1.0)))


axes = st.tuples(*[st.floats(-1, 1) for _ in range(3)]).filter(lambda a: np.linalg.norm(a) > 1e-3)


@settings(max_examples=60, deadline=None)
@given(axis=axes, angle=st.one_of(st.floats(0.0, 1e-3), st.floats(0.0, np.pi - 0.01)))
def test_log_inverts_exp(axis, angle):
    w = rotvec(axis, angle).astype(np.float32)
    np.testing.assert_allclose(np.asarray(exp_log(jnp.asarray(w))), w, atol=ROUND_TRIP_ATOL, rtol=1e-5)


@settings(max_examples=30, deadline=None)
@given(axis=axes, gap=st.floats(0.0, 1e-2))
def test_log_inverts_exp_near_pi(axis, gap):
    w = rotvec(axis, np.pi - gap).astype(np.float32)
    w_back = np.asarray(exp_log(jnp.asarray(w)))
    # At exactly pi, w and -w are the same rotation.
    err = min(np.abs(w_back - w).max(), np.abs(w_back + w).max()) if gap < 1e-6 else np.abs(w_back - w).max()
    assert err < NEAR_PI_ATOL


@settings(max_examples=30, deadline=None)
@given(axis=axes, angle=st.floats(0.0, np.pi))
def test_exp_matches_float64_rodrigues(axis, angle):
    w = rotvec(axis, angle)
    R = np.asarray(so3_exp(jnp.asarray(w, jnp.float32)))
    np.testing.assert_allclose(R, rodrigues64(w), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-6)


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_exp_log_keep_batch_shapes(batch):
    w = jnp.asarray(np.random.default_rng(0).normal(size=batch + (3,)) * 0.5, jnp.float32)
    R = so3_exp(w)
    assert R.shape == batch + (3, 3)
    assert so3_log(R).shape == batch + (3,)
    assert rotation_angle_deg(R, R).shape == batch


def test_gradients_are_finite_at_identity():
    zero = jnp.zeros(3, jnp.float32)
    grad_round_trip = jax.grad(lambda w: jnp.sum(so3_log(so3_exp(w))))(zero)
    np.testing.assert_allclose(np.asarray(grad_round_trip), np.ones(3), atol=1e-6)
    jac_exp = np.asarray(jax.jacfwd(so3_exp)(zero))
    generators = np.stack([np.asarray(so3_exp(jnp.eye(3)[i] * 1e-3)) - np.eye(3) for i in range(3)], -1) / 1e-3
    np.testing.assert_allclose(jac_exp, generators, atol=1e-3)
    grad_log = jax.grad(lambda R: jnp.sum(so3_log(R)))(jnp.eye(3, dtype=jnp.float32))
    grad_angle = jax.grad(lambda w: rotation_angle_deg(jnp.eye(3), so3_exp(w)))(zero)
    assert np.all(np.isfinite(np.asarray(grad_log)))
    assert np.all(np.isfinite(np.asarray(grad_angle)))


@pytest.mark.parametrize("angle", [1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0, 90.0, 150.0, 179.0])
def test_angle_is_accurate_in_float32(angle):
    """float32 inputs, float64 truth of the same (rounded) matrices: 1e-3 deg stays 1e-3 deg."""
    rng = np.random.default_rng(int(angle * 1e4))
    for _ in range(20):
        R_a = rodrigues64(rng.normal(size=3))
        R_b = R_a @ rodrigues64(rotvec(rng.normal(size=3), np.radians(angle)))
        R_a32, R_b32 = R_a.astype(np.float32), R_b.astype(np.float32)
        truth = angle64_deg(R_a32, R_b32)
        got = float(angle_deg(jnp.asarray(R_a32), jnp.asarray(R_b32)))
        assert abs(got - truth) <= 1e-6 * max(angle, 1.0), (angle, got, truth)
        # Rounding the inputs to float32 moves the true angle by ~2e-6 deg.
        assert abs(got - angle) <= 5e-6 * max(angle, 1.0), (angle, got)


def test_angle_of_identical_rotations_is_zero():
    R = so3_exp(jnp.asarray([0.3, -0.2, 0.1], jnp.float32))
    assert float(rotation_angle_deg(R, R)) == 0.0


def test_nearest_rotation_projects_onto_so3():
    rng = np.random.default_rng(0)
    R = rodrigues64(rng.normal(size=3))
    M = (R + 0.05 * rng.normal(size=(3, 3))).astype(np.float32)
    R_near = np.asarray(nearest_rotation(jnp.asarray(M)))
    np.testing.assert_allclose(R_near @ R_near.T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(R_near), 1.0, atol=1e-5)
    U, _, Vt = np.linalg.svd(M.astype(np.float64))
    expected = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    np.testing.assert_allclose(R_near, expected, atol=1e-5)
    # A reflection is mapped to a proper rotation, and a rotation to itself.
    reflection = np.diag([1.0, 1.0, -1.0]).astype(np.float32) @ R.astype(np.float32)
    assert np.linalg.det(np.asarray(nearest_rotation(jnp.asarray(reflection)))) == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(np.asarray(nearest_rotation(jnp.asarray(R, jnp.float32))), R, atol=1e-5)


def test_back_project_inverts_project():
    K = jnp.asarray([[400.0, 2.0, 255.5], [0.0, 410.0, 143.5], [0.0, 0.0, 1.0]], jnp.float32)
    rng = np.random.default_rng(1)
    uv = jnp.asarray(rng.uniform([0, 0], [511, 287], size=(4, 7, 2)), jnp.float32)
    z = jnp.asarray(rng.uniform(2, 12, size=(4, 7)), jnp.float32)
    X = back_project(K, uv, z)
    assert X.shape == (4, 7, 3)
    np.testing.assert_allclose(np.asarray(X[..., 2]), np.asarray(z))
    np.testing.assert_allclose(np.stack(project_floored(K, X[..., 0], X[..., 1], X[..., 2])[:2], -1), np.asarray(uv), atol=1e-3)

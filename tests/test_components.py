"""pose_variances.py: per-pair pose components (SPEC §3 step 8) and the authors' variants (§3a)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sgc_jax import stats
from sgc_jax.kernels import pose_variances as components
from sgc_jax.kernels.pose_variances import masked_mean, rotation_angle_deg_authors
from sgc_jax.kernels.so3 import so3_exp
from sgc_jax.kernels.uncertainty import pose_uncertainty

# The kernels are traced inside the engine's program; called alone here, each is jitted once.
pair_pose_components = jax.jit(components.pair_pose_components, static_argnames=("compat",))
trimmed_mean_jax = jax.jit(lambda values, valid, compat: stats.trimmed_mean(values, valid, compat, xp=jnp),
                           static_argnames=("compat",))

R_SLOTS = 6  # region slots per pair in these tests (padded, masked by `accepted`)
KEYS = ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var")
# float32 kernels vs float64 NumPy on O(1) values: a few ulps, accumulated over <= R_SLOTS terms.
RTOL = 1e-5


def rotations(rotvecs_rad) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(rotvecs_rad, np.float64)).as_matrix()


def angle_deg(R_a, R_b) -> float:
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def trimmed_mean_numpy(values, compat="spec") -> float:
    """docs/semantics.md §3.5's trimming written from np.percentile in float64 (the oracle)."""
    values = np.asarray(values, np.float64)
    if values.size == 0:
        return float("nan")
    q1, q3, p98 = np.percentile(values, [25, 75, 98])
    iqr = q3 - q1
    kept = values[(values >= q1 - (p98 - q3)) & (values <= p98)] if iqr > 0 else values[:0]
    if kept.size == 0:  # IQR = 0, or two distinct values the bounds fall between
        return float("nan") if compat == "authors" else float(values.mean())
    return float(kept.mean())


def components_numpy(R_local, t_local, accepted, R_g, t_g, rot_per_px, trans_per_px, compat="spec") -> dict:
    """Float64 twin of docs/semantics.md §3.5 over the accepted slots (n >= 1): each pose weighted by
    1 / per_px² under spec; equally, the global rotation term trimmed, under authors."""
    Rs, ts = R_local[accepted], t_local[accepted]
    w_rot, w_trans = ((None, None) if compat == "authors"
                      else (1 / rot_per_px[accepted] ** 2, 1 / trans_per_px[accepted] ** 2))
    R_mean = Rotation.from_rotvec(np.average(Rotation.from_matrix(Rs).as_rotvec(), axis=0, weights=w_rot)).as_matrix()
    t_mean = np.average(ts, axis=0, weights=w_trans)
    single = len(Rs) < 2
    to_camera = [angle_deg(R, R_g) ** 2 for R in Rs]
    return {
        "local_rot_var": 0.0 if single else np.average([angle_deg(R, R_mean) ** 2 for R in Rs], weights=w_rot),
        "local_trans_var": 0.0 if single else np.average(np.sum((ts - t_mean) ** 2, axis=1), weights=w_trans),
        "global_rot_var": (trimmed_mean_numpy(to_camera, compat) if compat == "authors"
                           else np.average(to_camera, weights=w_rot)),
        "global_trans_var": np.average(np.sum((ts - t_g) ** 2, axis=1), weights=w_trans),
    }


def random_pair(rng, n_accepted, spread_rad=0.05):
    """(R_local, t_local, accepted, R_g, t_g, rot_per_px [deg / px], trans_per_px): the poses'
    uncertainties per px of error spread over two decades, so the weights matter."""
    R_g = rotations(rng.normal(0, 0.3, 3))
    t_g = rng.normal(0, 1, 3)
    R_local = R_g @ rotations(rng.normal(0, spread_rad, (R_SLOTS, 3)))
    t_local = t_g + rng.normal(0, 0.1, (R_SLOTS, 3))
    accepted = np.zeros(R_SLOTS, bool)
    accepted[rng.choice(R_SLOTS, n_accepted, replace=False)] = True
    R_local[~accepted] = 0.0  # padding slots carry garbage
    t_local[~accepted] = 1e6
    rot_per_px, trans_per_px = 10.0 ** rng.uniform(-2, 0, R_SLOTS), 10.0 ** rng.uniform(-3, -1, R_SLOTS)
    rot_per_px[~accepted], trans_per_px[~accepted] = np.nan, np.nan
    return R_local, t_local, accepted, R_g, t_g, rot_per_px, trans_per_px


def run(R_local, t_local, accepted, R_g, t_g, rot_per_px, trans_per_px, compat="spec"):
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    out = pair_pose_components(f32(R_local), f32(t_local), jnp.asarray(accepted), f32(R_g), f32(t_g),
                               f32(rot_per_px), f32(trans_per_px), compat=compat)
    return {key: np.asarray(value) for key, value in out.items()}


def test_rigid_poses_give_zero_components():
    rng = np.random.default_rng(0)
    R_local, t_local, accepted, R_g, t_g, *noise = random_pair(rng, 4)
    R_local[accepted], t_local[accepted] = R_g, t_g
    out = run(R_local, t_local, accepted, R_g, t_g, *noise)
    assert int(out["n_poses"]) == 4
    for key in KEYS:
        assert float(out[key]) == pytest.approx(0.0, abs=1e-8), key


def test_single_pose_has_no_local_spread_and_its_distance_as_global():
    """One pose has no spread to measure: NaN under spec (docs/semantics.md §3.5), 0 under authors."""
    rng = np.random.default_rng(1)
    pair = random_pair(rng, 1, spread_rad=0.2)
    R_local, t_local, accepted, R_g, t_g, *_ = pair
    (j,) = np.flatnonzero(accepted)
    out, authors = run(*pair), run(*pair, compat="authors")
    assert np.isnan(out["local_rot_var"]) and np.isnan(out["local_trans_var"])
    assert float(authors["local_rot_var"]) == 0.0 and float(authors["local_trans_var"]) == 0.0
    assert float(out["global_rot_var"]) == pytest.approx(angle_deg(R_local[j], R_g) ** 2, rel=1e-4)
    assert float(out["global_trans_var"]) == pytest.approx(np.sum((t_local[j] - t_g) ** 2), rel=RTOL)


@pytest.mark.parametrize("compat", ["spec", "authors"])
@pytest.mark.parametrize("n_accepted", [2, 3, 6])
def test_matches_float64_formulas(n_accepted, compat):
    rng = np.random.default_rng(n_accepted)
    pair = random_pair(rng, n_accepted)
    out, expected = run(*pair, compat=compat), components_numpy(*pair, compat=compat)
    assert int(out["n_poses"]) == n_accepted
    for key in KEYS:
        if compat == "authors" and key == "global_rot_var" and np.isnan(expected[key]):
            assert np.isnan(out[key])  # the authors' IQR = 0 rejects every value
            continue
        # Rotation variances of ~3 deg spreads: float32 angles are good to ~1e-4 relative.
        assert float(out[key]) == pytest.approx(expected[key], rel=1e-3), key


def test_each_pose_counts_by_how_well_its_geometry_determines_it():
    """Twice the uncertainty per px of error counts a quarter as much; equal ones give the plain means."""
    accepted = jnp.ones(R_SLOTS, bool)
    weights = components.pose_weights(jnp.asarray([0.1, 0.1, 0.1, 0.2, 0.2, 0.2]), accepted)
    np.testing.assert_allclose(weights, [1, 1, 1, 0.25, 0.25, 0.25], rtol=RTOL)
    # one without a geometry (0 or not finite; an accepted pose's 4 inliers rule it out) takes the pair's median
    unknown = components.pose_weights(jnp.asarray([0.1, 0.2, 0.0, 0.2, jnp.nan, 0.2]), accepted)
    np.testing.assert_allclose(unknown, [1, 0.25, 0.25, 0.25, 0.25, 0.25], rtol=RTOL)
    rng = np.random.default_rng(11)
    R_local, t_local, accepted, R_g, t_g, *_ = random_pair(rng, R_SLOTS)
    ones = np.ones(R_SLOTS)
    equal = run(R_local, t_local, accepted, R_g, t_g, 0.3 * ones, 0.01 * ones)
    plain = components_numpy(R_local, t_local, accepted, R_g, t_g, ones, ones)
    for key in KEYS:
        assert float(equal[key]) == pytest.approx(plain[key], rel=1e-3), key


def test_a_poses_geometry_does_not_depend_on_how_well_it_fits():
    """The weight's geometry, a pose's error per px of tracking error, is the same for a region
    fitted exactly (residual sigma 0, an unmasked mover's lone layer) and one fitted through
    residuals, and it is the pose's uncertainty over its residual sigma where that is not 0."""
    rng = np.random.default_rng(13)
    X = np.column_stack([rng.uniform(-1, 1, (60, 2)), rng.uniform(3, 6, 60)]).astype(np.float32)
    K = np.array([[300.0, 0, 96], [0, 300.0, 72], [0, 0, 1]], np.float32)
    pose = np.array([[0.01, -0.02, 0.005, 0.05, 0.0, 0.02]], np.float32)
    R = np.asarray(so3_exp(jnp.asarray(pose[0, :3])))
    Y = X @ R.T + pose[0, 3:]
    exact_uv = (Y[:, :2] / Y[:, 2:]) * 300.0 + np.array([96.0, 72.0], np.float32)
    noisy_uv = exact_uv + rng.normal(0, 0.7, exact_uv.shape).astype(np.float32)
    region, inliers = np.ones(60, np.int32), np.ones(60, bool)
    exact, noisy = (pose_uncertainty(jnp.asarray(X), jnp.asarray(uv), jnp.asarray(region), jnp.asarray(K),
                                     jnp.asarray(pose), jnp.asarray(inliers)) for uv in (exact_uv, noisy_uv))
    assert float(exact.sigma_px[0]) < 1e-3 < float(noisy.sigma_px[0])
    for per_px in ("rot_per_px_deg", "trans_per_px"):
        assert float(getattr(exact, per_px)[0]) > 0
        np.testing.assert_allclose(getattr(exact, per_px), getattr(noisy, per_px), rtol=RTOL)
    np.testing.assert_allclose(noisy.rot_std_deg / noisy.sigma_px, noisy.rot_per_px_deg, rtol=RTOL)
    np.testing.assert_allclose(noisy.trans_std / noisy.sigma_px, noisy.trans_per_px, rtol=RTOL)


def test_spec_needs_the_poses_geometry():
    with pytest.raises(ValueError, match="rot_per_px and trans_per_px"):
        components.pair_pose_components(jnp.zeros((3, 3, 3)), jnp.zeros((3, 3)), jnp.ones(3, bool), jnp.eye(3),
                                        jnp.zeros(3))


def test_hundredth_of_a_degree_spread_is_resolved_in_float32():
    rng = np.random.default_rng(3)
    pair = random_pair(rng, 5, spread_rad=np.radians(0.01))
    out, expected = run(*pair), components_numpy(*pair)
    assert 1e-5 < expected["local_rot_var"] < 1e-3  # deg^2: ~0.01 deg deviations
    assert float(out["local_rot_var"]) == pytest.approx(expected["local_rot_var"], rel=1e-3)
    assert float(out["global_rot_var"]) == pytest.approx(expected["global_rot_var"], rel=1e-3)


def test_nan_only_where_the_poses_cannot_measure_it():
    """The global components need one pose, the local ones (a spread) two."""
    rng = np.random.default_rng(4)
    for n_accepted in range(R_SLOTS + 1):
        out = run(*random_pair(rng, n_accepted))
        for key in KEYS:
            assert np.isnan(out[key]) == (n_accepted < (2 if key.startswith("local") else 1)), (key, n_accepted)
        assert out["n_poses"].dtype == np.int32 and all(out[key].dtype == np.float32 for key in KEYS)


def test_authors_variant_uses_arccos_and_rejects_zero_iqr():
    rng = np.random.default_rng(5)
    pair = random_pair(rng, 1, spread_rad=0.2)
    out = run(*pair, compat="authors")
    assert np.isnan(out["global_rot_var"])  # one pose: IQR == 0 rejects every value
    assert float(out["global_trans_var"]) == pytest.approx(run(*pair)["global_trans_var"])
    tiny = jnp.asarray(rotations([[np.radians(1e-3), 0.0, 0.0]])[0], jnp.float32)
    assert float(rotation_angle_deg_authors(jnp.eye(3), tiny)) == 0.0  # float32 arccos loses it
    big = rotations([[0.0, 0.0, np.radians(30.0)]])[0]
    assert float(rotation_angle_deg_authors(jnp.eye(3), jnp.asarray(big, jnp.float32))) == pytest.approx(30.0, rel=1e-5)


def trimming_cases():
    rng = np.random.default_rng(6)
    cases = []
    for n in range(0, R_SLOTS + 1):
        cases.append(rng.exponential(1.0, n))  # continuous values
        cases.append(rng.integers(0, 3, n).astype(float))  # many ties, IQR == 0 often
    cases.append(np.array([1.0, 1.0, 1.0, 1.0, 7.0]))  # IQR == 0 with an outlier
    cases.append(np.array([2.0, 5.0]))  # two distinct values: the bounds reject both
    return cases


@pytest.mark.parametrize("compat", ["spec", "authors"])
def test_trimmed_mean_matches_numpy_percentiles_in_jax_and_numpy(compat):
    for values in trimming_cases():
        padded = np.full(R_SLOTS, np.nan, np.float32)
        padded[: values.size] = values
        valid = np.arange(R_SLOTS) < values.size
        expected = trimmed_mean_numpy(values.astype(np.float32), compat)
        got = float(trimmed_mean_jax(jnp.asarray(padded), jnp.asarray(valid), compat=compat))
        np.testing.assert_allclose(got, expected, rtol=RTOL, err_msg=str(values))
        host = float(stats.trimmed_mean(padded.astype(np.float64), valid, compat))
        np.testing.assert_allclose(host, expected, rtol=1e-12, err_msg=str(values))  # float64 throughout


def test_masked_mean_ignores_masked_values_and_is_nan_with_none():
    values = jnp.array([[1.0, 2.0], [3.0, 4.0], [np.nan, np.inf]])
    np.testing.assert_allclose(masked_mean(values, jnp.array([True, True, False])), [2.0, 3.0])
    assert np.isnan(float(masked_mean(jnp.array([1.0, 2.0]), jnp.array([False, False]))))


def test_batch_of_pairs_equals_loop():
    rng = np.random.default_rng(7)
    pairs = [random_pair(rng, n) for n in (0, 1, 3, 6)]
    stacked = [jnp.asarray(np.stack(arrays), jnp.bool_ if arrays[0].dtype == bool else jnp.float32)
               for arrays in zip(*pairs)]  # noise included: (pairs, R_SLOTS)
    batch = jax.vmap(pair_pose_components)(*stacked)
    for i, pair in enumerate(pairs):
        single = run(*pair)
        for key in single:
            np.testing.assert_array_equal(np.asarray(batch[key][i]), single[key], err_msg=key)


def test_unknown_compat_raises():
    with pytest.raises(ValueError, match="compat"):
        pair_pose_components(jnp.zeros((3, 3, 3)), jnp.zeros((3, 3)), jnp.ones(3, bool), jnp.eye(3), jnp.zeros(3),
                             compat="paper")

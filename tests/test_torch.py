"""PyTorch tensors in and out of the Scorer (docs/semantics.md §9.5): the same numbers as the JAX
Scorer, tensors shared with JAX where DLPack allows and every copy said, ClipFormatError naming the
array, and sgc_smooth's gradients reaching torch leaves as jax.grad gives them."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from scenes import DEMO_BATCH_SHAPE
from test_gradients import FD_STEP, FLOATS, SHAPE as GRADIENT_SHAPE, gradient_clip

from sgc_jax import ClipFormatError, Scorer
from sgc_jax.engines.jax_engine.smooth_stage import smooth_stage
from sgc_jax.research.perturb import perturb_clip
from sgc_jax.research.synth import demo_corpus
from sgc_jax.scoring.scorer import batch_of
from sgc_jax.torch import TensorCopyWarning, TorchScorer, batch_tensors, to_jax

# torch's float32 gradient (at the float32 inputs) against float64 central differences of the
# score with the forward pass's choices held (test_gradients.py's check, FD_STEP there), along a
# random direction d: the error of sum_i g_i d_i relative to sum_i |g_i d_i|, float32's rounding of
# its terms (the sum itself may cancel: K's terms along the test's direction cancel 195-fold).
# Measured over 8 directions: <= 2e-5 for five inputs, <= 1.4e-4 for K, each of whose terms passes
# through a back-projection and a projection with the same K (0.01-2.8 % of the sum itself).
TORCH_FD_RTOL = 5e-4


@pytest.fixture(scope="module")
def batch():
    return batch_of(demo_corpus()[:DEMO_BATCH_SHAPE[0]])


@pytest.fixture(scope="module")
def scorer():
    return TorchScorer(DEMO_BATCH_SHAPE)


@pytest.fixture(scope="module")
def expected(batch):
    return {name: np.asarray(value) for name, value in Scorer(DEMO_BATCH_SHAPE)(batch).items()}


def test_torch_scorer_gives_the_jax_scorers_numbers_as_torch_tensors(scorer, batch, expected):
    out = scorer(batch_tensors(batch))
    assert set(out) == set(expected)
    for name, value in out.items():
        assert isinstance(value, torch.Tensor) and value.device == torch.device("cpu"), name
        np.testing.assert_array_equal(value.numpy(), expected[name], err_msg=name)


def test_compact_float32_and_bool_tensors_reach_jax_without_a_copy():
    for tensor in (torch.rand(3, 64, 80), torch.rand(3, 64, 80) > 0.5, torch.rand(80, 64).T,
                   torch.randint(0, 2, (3, 64, 80), dtype=torch.uint8), torch.randint(0, 9, (3, 64), dtype=torch.int32)):
        array, why = to_jax(tensor, "depth", torch.device("cpu"))
        assert why == "" and array.unsafe_buffer_pointer() == tensor.data_ptr()
        np.testing.assert_array_equal(np.asarray(array), tensor.numpy())


def test_every_copy_is_said_and_scores_as_the_shared_tensor_does(scorer, batch, expected):
    tensors = batch_tensors(batch)
    wide = torch.zeros((*tensors["depth"].shape[:-1], tensors["depth"].shape[-1] + 3))
    wide[..., :-3] = tensors["depth"]
    altered = {**tensors, "depth": wide[..., :-3],  # a slice: strides DLPack cannot share
               "track_vis": tensors["track_vis"].long(),  # int64 without x64
               "static_mask": tensors["static_mask"].to(torch.uint8),  # shared: masks may be numbers
               "track_prev": tensors["track_prev"].double().requires_grad_(True)}
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        out = scorer(altered)
    assert set(scorer.copies) == {"depth", "track_vis", "track_prev"}
    assert "contiguous" in scorer.copies["depth"] and "int64" in scorer.copies["track_vis"]
    assert "float64" in scorer.copies["track_prev"]
    assert {str(w.message).split("'")[1] for w in said if w.category is TensorCopyWarning} == set(scorer.copies)
    for name in ("sgc", "reward", "status"):
        np.testing.assert_array_equal(out[name].numpy(), expected[name], err_msg=name)
    scorer(tensors)
    assert scorer.copies == {}


def test_a_wrong_tensor_raises_clip_format_error_naming_the_array(scorer, batch):
    tensors = batch_tensors(batch)
    with pytest.raises(ClipFormatError, match="'depth'.*shape \\(4, 8, 96, 128\\)"):
        scorer({**tensors, "depth": tensors["depth"][:, :, :90]})
    with pytest.raises(ClipFormatError, match="'track_prev'.*float"):
        scorer({**tensors, "track_prev": tensors["track_prev"].int()})
    with pytest.raises(ClipFormatError, match="'K'.*torch.Tensor.*ndarray"):
        scorer({**tensors, "K": batch["K"]})
    with pytest.raises(ClipFormatError, match="'depth'.*on cpu.*on meta"):
        scorer({**tensors, "depth": torch.empty(tensors["depth"].shape, device="meta")})


@pytest.fixture(scope="module")
def gradient_batch():
    clean = gradient_clip(3)
    return batch_of([clean, perturb_clip(clean, "depth_warp", 0.5)])


@pytest.fixture(scope="module")
def differentiable():
    return TorchScorer(GRADIENT_SHAPE, differentiable=True)


@pytest.fixture(scope="module")
def torch_gradients(differentiable, gradient_batch):
    """d sum(sgc_smooth) / d every float input, by loss.backward() on torch leaves."""
    tensors = batch_tensors(gradient_batch)
    leaves = {name: tensors[name].clone().requires_grad_(True) for name in FLOATS}
    out = differentiable({**tensors, **leaves})
    assert out["sgc_smooth"].requires_grad and not out["sgc"].requires_grad
    out["sgc_smooth"].sum().backward()
    return {name: leaf.grad for name, leaf in leaves.items()}


def test_loss_backward_reaches_torch_leaves_with_jax_grads_gradients(differentiable, gradient_batch, torch_gradients):
    batch = gradient_batch
    expected = jax.grad(lambda x: differentiable.scorer({**batch, **x})["sgc_smooth"].sum())(
        {n: batch[n] for n in FLOATS})
    for name in FLOATS:
        grad = torch_gradients[name]
        assert grad is not None and grad.dtype == torch.float32, name
        np.testing.assert_array_equal(grad.numpy(), np.asarray(expected[name]), err_msg=name)


def test_torch_gradients_agree_with_finite_differences_of_the_score_with_its_choices_held(
        differentiable, gradient_batch, torch_gradients):
    scorer = differentiable.scorer
    frozen, arrays = scorer.choices(gradient_batch), scorer.clip_arrays(gradient_batch)
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        base = {n: jnp.asarray(getattr(arrays, n), jnp.float64) for n in FLOATS}
        score = jax.jit(lambda x: smooth_stage(arrays._replace(**x), frozen, scorer.bucket, scorer.config,
                                               scorer.calibration).sum())
        for name in FLOATS:
            x = np.asarray(base[name])
            direction = np.abs(x) * np.clip(rng.standard_normal(x.shape), -2.5, 2.5)  # relative moves
            finite = float(score({**base, name: base[name] + FD_STEP * direction})
                           - score({**base, name: base[name] - FD_STEP * direction})) / (2 * FD_STEP)
            terms = torch_gradients[name].numpy().astype(np.float64) * direction
            analytic = float(np.sum(terms))
            assert abs(finite - analytic) <= TORCH_FD_RTOL * np.sum(np.abs(terms)), (name, finite, analytic)

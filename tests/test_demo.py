"""``sgc-jax demo`` tells the truth: every claim it prints about its corpus holds in both engines."""

import pytest

from sgc_jax import score_batch
from sgc_jax.research.synth import DEMO_CLAIMS, demo_claims, demo_corpus


@pytest.fixture(scope="module")
def corpus():
    return demo_corpus()


@pytest.mark.parametrize("engine", ("jax", "reference"))
def test_every_demo_claim_holds(corpus, engine):
    result = score_batch(corpus, engine=engine)
    assert all(c.status == "ok" for c in result.clips), [(c.clip_id, c.reason) for c in result.clips]
    claims = demo_claims({c.clip_id: c.sgc for c in result.clips})
    assert len(claims) == len(DEMO_CLAIMS)
    assert all(holds for _, holds in claims), (engine, claims, result.table())

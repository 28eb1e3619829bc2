"""The suite's synthetic scenes, in one place (``from scenes import SCENE``).

The JAX engine compiles its programs once per shape bucket and static config: a scene of a new
size costs the suite a minute or more of compiling on a 2-core box. Every clip the JAX engine
scores in a test is therefore built on one of the first three shapes (or a variant that pads to
the same bucket: 3 frames pad to 4); the other scenes are scored by the reference engine only, or
not at all.
"""

# Two planar layers (one slanted) and four static spheres: every depth region is a curved 3D point
# set, well conditioned. Small planar patches are the ill-posed case where any PnP-RANSAC
# (OpenCV's included) may return the planar-ambiguity twin pose (docs/semantics.md §3.3).
SCENE = dict(n_layers=2, static_spheres=4, height=120, width=160, n_tracks=2048, n_frames=4)  # bucket 4, 128x192, 2048
# The agreement corpus's second size (research.agreement) and the sensitivity ladders'.
SMALL_SCENE = dict(n_layers=2, static_spheres=4, height=96, width=128, n_tracks=1024, n_frames=4)  # 4, 128x128, 1024
# The demo corpus's shape (research.synth.demo_corpus; `sgc-jax demo` compiles it first in CI) and the notebooks'.
DEMO_SCENE = dict(n_layers=3, static_spheres=4, height=96, width=128, n_tracks=1024, n_frames=8)  # 8, 128x128, 1024
# A Scorer's batch of 4 demo clips (B, T, H, W, P): test_scorer.py's, and the one test_compile_cache.py
# starts in new processes (its stages compiled once for both).
DEMO_BATCH_SHAPE = (4, DEMO_SCENE["n_frames"], DEMO_SCENE["height"], DEMO_SCENE["width"], DEMO_SCENE["n_tracks"])

# Scored by the reference engine only, or not at all:
TINY = dict(n_layers=1, static_spheres=2, height=64, width=80, n_tracks=256, n_frames=3)  # CLI and table tests
MICRO = dict(n_layers=1, static_spheres=1, height=24, width=32, n_tracks=64, n_frames=3, with_frames=False)  # bad files
IMPORT_SCENE = dict(n_layers=2, static_spheres=2, height=96, width=128, n_tracks=512, n_frames=4)  # estimator files
SYNTH_SCENE = dict(n_frames=4, height=48, width=64, n_tracks=256)  # the generator's own tests
# Six small planar layers and 400 tracks per pair: the near layers carry 6-30 tracks each over a few
# percent of the image, with 1 px noise (the region-quality rule's case; bench/region_quality.py at full size).
SPARSE_SCENE = dict(n_layers=6, static_spheres=0, n_tracks=400, height=192, width=320, n_frames=4)

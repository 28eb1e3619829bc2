"""The validation protocol (docs/semantics.md §7.4): a FIT split of synthetic scenes on which every
constant of the default score may be chosen, and a TEST split, fixed before any tuning, on which
its claims are reported.

The splits share no seed. TEST also holds what FIT lacks: scene layouts (more and fewer planar
layers), image sizes (120x160, 192x256), frame counts (6, 12) and camera motions (other speeds, a
forward dolly). Every scene is consistent; a *cell* is one scene under one noise model
(:data:`sgc_jax.research.noise.NOISE_MODELS`) at one level and one track count, scored clean, under
each inconsistency and its consistent twin:

- ``warp``, ``squeeze``, ``depth_warp`` (:mod:`sgc_jax.research.perturb`) at :data:`SEVERITIES`,
  against the clean scene;
- ``mover``: one moving object left unmasked, against the same scene with it masked. A mover
  with fewer usable tracks on it per pair than an accepted pose needs
  (``SGCConfig.min_region_points``) is *hidden*: no pose can be fitted to it, and among a layer's
  tracks it is RANSAC's outliers (:func:`tracks_on_mover`); the benchmarks report it apart.

Noise is dealt after the inconsistency, from a seed of the cell, so a scene and its inconsistent
version carry the same tracker errors.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import os
from typing import Any, Callable, Iterator, Sequence

import cv2
import numpy as np

from ..config import SGCConfig
from ..io.clip import Clip
from ..io.tables import write_csv
from .noise import NOISE_MODELS, add_noise
from .perturb import PERTURBATIONS, perturb_clip
from .synth import SceneSpec, synth_clip

#: Seeds of each split; FIT's include the shipped calibration corpus's (0, 1) and the benchmarks' (10-12).
FIT_SEEDS = range(0, 100)
TEST_SEEDS = range(5800, 5900)
NOISE_LEVELS_PX = (0.25, 0.5, 1.0, 2.0)
TRACK_COUNTS = (200, 1000, 4096)
# A second draw of a noise adds this to its seed: above every split's and bench's own seeds, so
# no two draws share one.
NOISE_DRAW_STRIDE = 10_000_000
SEVERITIES = (0.1, 0.25, 0.5)
INCONSISTENCIES = (*PERTURBATIONS, "mover")


@dataclasses.dataclass(frozen=True)
class ProtocolScene:
    """One consistent scene of a split: a seed and the :class:`~sgc_jax.research.synth.SceneSpec`
    fields that differ from the defaults (tracks and noise are set per cell)."""

    name: str
    seed: int
    spec: dict[str, Any]

    def clip(self, n_tracks: int, *, moving: bool = False) -> Clip:
        """The exact clip with ``n_tracks`` tracks per pair; ``moving``: with one moving object, masked."""
        return synth_clip(seed=self.seed, clip_id=self.name, n_tracks=n_tracks, with_frames=False,
                          moving_objects=int(moving), **self.spec)


def _scene(name: str, seed: int, layers: int, spheres: int, size: tuple[int, int], frames: int,
           rot: float, trans: float, motion: str = "orbit") -> ProtocolScene:
    return ProtocolScene(name, seed, dict(n_layers=layers, static_spheres=spheres, height=size[0], width=size[1],
                                          n_frames=frames, rot_deg_per_frame=rot, trans_per_frame=trans,
                                          camera_motion=motion))


#: FIT: the calibration corpus's and the benchmarks' layouts and sizes, 8 frames, orbiting cameras at
#: the corpus's speeds.
FIT_SCENES = (
    _scene("fit-0", 20, 3, 4, (144, 192), 8, 1.5, 0.15),
    _scene("fit-1", 21, 2, 4, (144, 192), 8, 0.5, 0.05),
    _scene("fit-2", 22, 3, 4, (96, 128), 8, 3.0, 0.3),
    _scene("fit-3", 23, 2, 4, (96, 128), 8, 1.5, 0.15),
    _scene("fit-4", 24, 3, 4, (144, 192), 8, 3.0, 0.3),
    _scene("fit-5", 25, 2, 4, (144, 192), 8, 1.5, 0.15),
)

#: TEST: two scenes like FIT's (other seeds), then layouts, sizes, frame counts and motions FIT lacks.
TEST_SCENES = (
    _scene("test-0", 5800, 3, 4, (144, 192), 8, 1.5, 0.15),
    _scene("test-1", 5801, 2, 4, (96, 128), 8, 0.5, 0.05),
    _scene("test-2", 5802, 5, 2, (120, 160), 6, 1.0, 0.1),  # many planar layers, few spheres
    _scene("test-3", 5803, 1, 6, (192, 256), 8, 2.0, 0.25),  # mostly curved structure
    _scene("test-4", 5804, 4, 3, (144, 192), 12, 1.0, 0.12, "forward"),  # a dolly in
    _scene("test-5", 5805, 3, 4, (120, 160), 8, 2.5, 0.05),  # rotation-dominated pan, little parallax
)

SPLITS = {"fit": FIT_SCENES, "test": TEST_SCENES}

#: UNSEEN: scenes drawn at random over (and beyond) both splits' ranges, for reports only: six TEST
#: scenes sample few layouts. Scene k has seed UNSEEN_SEEDS[k] and its spec from ``random_scene``.
UNSEEN_SEEDS = range(7200, 7300)
UNSEEN_SIZES = ((96, 128), (120, 160), (144, 192), (192, 256))
#: FIT's own random scenes, drawn as the unseen ones from FIT seeds no other FIT scene uses (the
#: calibration corpus 0-1, the benchmarks 10-12, FIT_SCENES 20-25): constants may be chosen on them.
FIT_POOL_SEEDS = range(30, 100)
#: HELD_OUT: drawn as the unseen scenes, kept unread until the translation scale's cut was chosen on FIT, then
#: read once to report it (2026-12-01, docs/semantics.md §7.4); like the unseen pool, no longer unread.
HELD_OUT_SEEDS = range(7300, 7400)
RANDOM_POOLS = {"unseen": UNSEEN_SEEDS, "fit": FIT_POOL_SEEDS, "held-out": HELD_OUT_SEEDS}


def random_scene(k: int, fovs: Sequence[float] = (60.0,), pool: str = "unseen") -> ProtocolScene:
    """Scene k of a random pool (``RANDOM_POOLS``: "unseen" and "held-out", report-only, or "fit"): size among
    ``UNSEEN_SIZES``, 6, 8 or 12 frames, 1-5 planar layers, 2-6 static spheres, 0.5-3 deg and
    0.05-0.3 depth units of motion a frame, orbit (2 in 3) or forward, the field of view among
    ``fovs`` [deg]; drawn from ``numpy.random.default_rng(RANDOM_POOLS[pool][k])``."""
    seed = RANDOM_POOLS[pool][k]
    rng = np.random.default_rng(seed)
    height, width = UNSEEN_SIZES[rng.integers(len(UNSEEN_SIZES))]
    spec = dict(height=height, width=width, n_frames=int(rng.choice([6, 8, 12])), n_layers=int(rng.integers(1, 6)),
                static_spheres=int(rng.integers(2, 7)), rot_deg_per_frame=round(float(rng.uniform(0.5, 3.0)), 2),
                trans_per_frame=round(float(rng.uniform(0.05, 0.3)), 2),
                camera_motion=str(rng.choice(["orbit", "orbit", "forward"])), fov_deg=float(rng.choice(fovs)))
    return ProtocolScene(f"unseen-{k}" if pool == "unseen" else f"{pool}-pool-{k}", seed, spec)


#: The loader checks' pools (bench/disparity_line.py, bench/pose_lines.py): each random scene under these
#: noise models at these levels, 1,000 tracks.
CHECK_POOL_MODELS, CHECK_POOL_LEVELS_PX = ("iid-both", "correlated", "depth", "outliers"), (0.5, 2.0)


def check_pool_clips(pool: str, scenes: int) -> Iterator[tuple[float, Clip]]:
    """(noise level [px], clip) for scenes 0..``scenes``-1 of a random pool, 1,000 tracks, under each of
    CHECK_POOL_MODELS at each of CHECK_POOL_LEVELS_PX; the noise seeded by scene, model and level."""
    for k in range(scenes):
        scene = random_scene(k, pool=pool)
        clean = scene.clip(1000)
        for j, model in enumerate(CHECK_POOL_MODELS):
            for px in CHECK_POOL_LEVELS_PX:
                yield px, add_noise(clean, NOISE_MODELS[model].replace(px=px), seed=scene.seed * 100 + j * 10 + int(2 * px))


@dataclasses.dataclass(frozen=True)
class Cell:
    """One scene under one noise model, level and track count; its rows share one noise seed.
    ``draw`` > 0 deals an independent draw of the same noise (draw 0 is the protocol's)."""

    scene: ProtocolScene
    noise_model: str
    noise_px: float
    n_tracks: int
    draw: int = 0

    @property
    def noise_seed(self) -> int:
        return (self.draw * NOISE_DRAW_STRIDE + self.scene.seed * 1000 + NOISE_LEVELS_PX.index(self.noise_px) * 100
                + sorted(NOISE_MODELS).index(self.noise_model) * 10 + TRACK_COUNTS.index(self.n_tracks))


def cells(split: str, noise_models=tuple(NOISE_MODELS), levels=NOISE_LEVELS_PX, tracks=TRACK_COUNTS,
          draw: int = 0) -> Iterator[Cell]:
    """Every cell of a split, scene-major."""
    for scene, model, px, n in itertools.product(SPLITS[split], noise_models, levels, tracks):
        yield Cell(scene, model, px, n, draw)


def exact_variants(scene: ProtocolScene, n_tracks: int, inconsistencies=INCONSISTENCIES,
                   severities=SEVERITIES) -> list[tuple[Clip, str, float]]:
    """(exact clip, inconsistency or "" for consistent, severity) of a scene: the consistent scene,
    each perturbation at each severity, and for ``mover`` the scene with one moving object masked
    (consistent, kind ``"mover-masked"``) and the same clip without its mask (severity 1)."""
    clean = scene.clip(n_tracks)
    out: list[tuple[Clip, str, float]] = [(clean, "", 0.0)]
    for kind in inconsistencies:
        if kind == "mover":
            masked = scene.clip(n_tracks, moving=True)
            unmasked = dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")
            out += [(masked, "mover-masked", 0.0), (unmasked, "mover", 1.0)]
        else:
            out += [(perturb_clip(clean, kind, s, seed=scene.seed), kind, s) for s in severities]
    return out


def tracks_on_mover(masked: Clip, min_track_conf: float, margin_px: int = SceneSpec.mask_margin_px) -> float:
    """Mean over pairs of the usable tracks whose frame-i−1 position lies on the moving object of a
    ``mover-masked`` clip: its dynamic mask less the mask's margin (``margin_px``, the synthesis's
    ``SceneSpec.mask_margin_px`` by default)."""
    kernel = np.ones((2 * margin_px + 1,) * 2, np.uint8)
    on_object = np.stack([cv2.erode((~static).astype(np.uint8), kernel) > 0 for static in masked.static_mask[:-1]])
    pairs, H, W = on_object.shape
    column, row = (np.clip(np.rint(masked.track_prev[..., a]).astype(np.int64), 0, size - 1)
                   for a, size in ((0, W), (1, H)))
    hit = on_object[np.arange(pairs)[:, None], row, column] & masked.usable_tracks(min_track_conf)
    return float(hit.sum(axis=1).mean())


def hidden_movers(split: str, tracks: Sequence[int], config: SGCConfig) -> set[tuple[str, int]]:
    """(scene, track count) pairs of a split whose mover carries fewer than
    ``config.min_region_points`` usable tracks per pair (:func:`tracks_on_mover`)."""
    return {(scene.name, n) for scene, n in itertools.product(SPLITS[split], tracks)
            if tracks_on_mover(scene.clip(n, moving=True), config.min_track_conf) < config.min_region_points}


def cell_clips(cell: Cell, inconsistencies=INCONSISTENCIES, severities=SEVERITIES,
               exact: list[tuple[Clip, str, float]] | None = None) -> list[tuple[Clip, str, float]]:
    """``exact_variants`` of the cell's scene with the cell's noise; ``exact``: those variants,
    when already made for the scene and track count (they do not depend on the noise)."""
    model = NOISE_MODELS[cell.noise_model].replace(px=cell.noise_px)
    if exact is None:
        exact = exact_variants(cell.scene, cell.n_tracks, inconsistencies, severities)
    return [(add_noise(c, model, cell.noise_seed), kind, s) for c, kind, s in exact]


def consistent_twin(kind: str) -> str:
    """The kind of the consistent clip an inconsistency is compared with."""
    return "mover-masked" if kind == "mover" else ""


def detection_table(rows: list[dict]) -> dict[tuple[str, float], float]:
    """(inconsistency, severity) -> the share of cells where it scores strictly above its
    consistent twin (an inconsistency without a score is not above; a twin without one counts as 0);
    rows carry ``cell`` (any hashable), ``kind``, ``severity`` and ``sgc``."""
    by_cell: dict[Any, dict[tuple[str, float], float]] = {}
    for r in rows:
        by_cell.setdefault(r["cell"], {})[(r["kind"], r["severity"])] = r["sgc"]
    hits: dict[tuple[str, float], list[bool]] = {}
    for scores in by_cell.values():
        for (kind, severity), sgc in scores.items():
            if kind in ("", "mover-masked"):
                continue
            twin = scores.get((consistent_twin(kind), 0.0))
            if twin is None:
                continue
            above = np.nan_to_num(sgc, nan=-1.0) > np.nan_to_num(twin, nan=0.0)
            hits.setdefault((kind, severity), []).append(bool(above))
    return {key: float(np.mean(v)) for key, v in sorted(hits.items())}


def interval_coverage(draws: Sequence[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scored draws of one clip's noise (``ClipResult``s) -> (covered, width, sgc), each (n,):
    whether each draw's 90 % interval holds the median SGC of all the draws (docs/semantics.md
    §5.6), the interval's width and the draw's SGC."""
    sgc, lo, hi = (np.array([getattr(c, k) for c in draws]) for k in ("sgc", "sgc_lo", "sgc_hi"))
    median = np.median(sgc)
    return (lo <= median) & (median <= hi), hi - lo, sgc


def write_rows(path: str | os.PathLike, rows: Sequence[dict]) -> None:
    """A benchmark's rows as CSV, columns in the first row's order (NaN as an empty cell)."""
    write_csv(path, rows, list(rows[0]))


def read_rows(path: str | os.PathLike, text: Sequence[str], integers: Sequence[str] = ()) -> list[dict]:
    """Rows ``write_rows`` wrote: the ``text`` columns as written, ``integers`` as int, the rest float
    (an empty cell NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for key, value in r.items():
            if key in integers:
                r[key] = int(value)
            elif key not in text:
                r[key] = float(value) if value not in ("", "nan") else float("nan")
    return rows


def rows_scored_or_read(rows_path: str | os.PathLike | None, out_path: str | os.PathLike | None,
                        score: Callable[[], list[dict]], text: Sequence[str],
                        integers: Sequence[str] = ()) -> list[dict]:
    """A benchmark's rows: read from ``rows_path`` (a CSV an earlier run wrote, ``read_rows``), or
    made by ``score()`` and written to ``out_path`` when one is given."""
    if rows_path:
        return read_rows(rows_path, text, integers)
    rows = score()
    if out_path:
        write_rows(out_path, rows)
    return rows

"""Consistent scenes no constant was fitted to and no split holds (docs/semantics.md §7.4): random
layouts, sizes, frame counts, camera motions and fields of view, each scene drawn once per noise
cell. A probe beside the protocol's six TEST scenes, for what they do not sample.

    python bench/unseen_scenes.py [--scenes 24] [--first 0] [--tracks 1000] [--fovs 60]
                                  [--depth-scale-rms 0.02] [--camera-rot-deg 0.1 0.3]
                                  [--camera-step-rel 0.1] [--models correlated depth outliers]
                                  [--perturb 0.25] [--pool fit|held-out] [--noise-draw K] [--out rows.csv]
                                  [--back-wall-depth 1000 [--sky-invalid]] [--spec '{"n_layers": 0}']
                                  [--focal-scale 0.9] [--focal-jitter 0.01 [--one-k]]
                                  [--depth-resample 2] [--depth-bits 8] [--depth-edge-ratio 1.2]
                                  [--depth-offset-rms 0.03]
                                  [--rows rows.csv] [--against other.csv]

Scene k, from ``--first`` on, is ``research.protocol.random_scene(k, fovs)`` (seeds 7200-7299,
neither FIT's nor TEST's; with ``--pool fit`` the same sampler on FIT's seeds 30-99,
``FIT_POOL_SEEDS``, where constants may be chosen; with ``--pool held-out`` on seeds 7300-7399,
read once, to report the translation scale's cut): size among the protocol's four, 6, 8 or 12
frames, 1-5 planar layers, 2-6 static spheres, 0.5-3 deg and 0.05-0.3 depth units of motion a
frame, orbit or forward, the field of view from ``--fovs``. Noise cells: independent Gaussian
track errors at frame i only and at both ends, 0.5 and 2 px (research.noise); with
``--depth-scale-rms r`` also iid-both 0.5 px with each frame's depth multiplied by exp(r N(0, 1))
(``NoiseModel.depth_scale_rel``), a per-frame scale error such as monocular depth estimated frame
by frame leaves; with ``--camera-rot-deg a ...`` / ``--camera-step-rel b ...`` also iid-both 0.5 px
with each camera turned about its centre by a rotation of RMS a degrees per axis / its centre moved
by b median camera steps per axis, independently per frame (``NoiseModel.camera_rot_deg``,
``camera_step_rel``: a pose estimator's errors, which the score takes as exact); with ``--models``
also those protocol noise models (correlated track errors, depth noise, outliers; research.noise)
at 0.5 and 2 px. ``--back-wall-depth Z`` moves every scene's back wall from 12 to Z depth units, a
sky-like backdrop behind layers at 2-12 (``SceneSpec.back_wall_depth``); ``--sky-invalid`` then sets
the depth there to 0 (invalid), as a sky mask would (docs/semantics.md §3.1, "A sky"). ``--spec JSON``
sets ``SceneSpec`` fields on every scene, e.g. ``'{"n_layers": 0, "static_spheres": 0}'``: a world of
one plane, the back wall alone (docs/semantics.md §3.10, "A world of one plane"); ``'{"ground_height":
1.5}'``: a ground 1.5 units below the camera, a floor or a street, which neither split holds (§7.4). ``--focal-scale f``
gives every clip a K whose focal lengths are f times the true ones, as a camera estimator's error
(the same K in every frame; docs/semantics.md §3.10, "A pose estimator's errors in the cameras");
``--focal-jitter r`` multiplies each frame's by its own factor exp(r N(0, 1)), as per-frame estimates
(VGGT's, DA3's) scatter (§1.5, "One K for a clip"); ``--one-k`` then gives every frame their median,
as ``sgc-jax import`` does. ``--depth-resample F`` gives every clip (the perturbed ones after their
perturbation) the depth a network predicting at 1/F of the frame's size leaves once resized back:
each frame shrunk F times by area averaging (over F x F blocks at a whole F), then bilinearly
enlarged, so depth edges become ramps of mixed depths; ``--depth-bits N`` stores each clip's inverse
depth in N bits over its range, as depth saved as 8- or 16-bit disparity images is;
``--depth-edge-ratio R`` then makes the depth invalid on the ramps at edges (a 3 x 3 neighbourhood
spanning more than R, the pixel over 5 % from both its least and greatest depth), as ``sgc-jax
import --depth-edge-ratio`` does (docs/semantics.md §3.6, "Smooth depth edges"). ``--depth-offset-rms r``
adds to each frame's depth its own offset, r N(0, 1) times the clip's median depth, the same draw for a
scene's consistent and perturbed clips in every cell (``NoiseModel.depth_offset_rel``: a relative-depth
model aligned frame by frame; docs/semantics.md §3.10).
With ``--perturb s`` each cell also scores the three perturbations at severity s, made on the exact
clip and given the consistent clip's noise draw (paired, as bench/validation.py), and prints the
share of cells where each scores above its consistent twin: detection on layouts no constant was
fitted to; and, unpaired, the share of consistent and perturbed clips whose SGC and whose ``sgc_lo``
lie above 0.05, 0.1 and 0.2 (what a threshold on a corpus without twins would flag). Prints each
scene's row and, per cell, the clips above 0.10, the largest and the statuses; ``--out`` writes one row per clip (pandas-ready), ``--rows`` prints the tables from such
a file, and ``--against ROWS`` compares them with rows of the same scenes scored otherwise (another
tree, config or calibration): per cell the clips above 0.10 and the detections there -> here, their
sums and the largest fall of one cell's perturbation (the terms issue 58's rules are written in).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np

from sgc_jax import score_batch
from sgc_jax.io.depth_edges import without_ramps
from sgc_jax.research.noise import NOISE_MODELS, NoiseModel, add_noise, enlarged_depth
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.protocol import (
    NOISE_DRAW_STRIDE,
    RANDOM_POOLS,
    detection_table,
    random_scene,
    read_rows,
    rows_scored_or_read,
)

# model, px, depth scale, camera rotation [deg], camera centre [steps]; a cell's noise seed is scene
# seed * 10 + its index among these and the --depth-scale-rms and camera cells (the depth-scale cell: 4)
CELLS = tuple((model, px, 0.0, 0.0, 0.0) for model, px in (("iid-curr", 0.5), ("iid-both", 0.5), ("iid-curr", 2.0),
                                                             ("iid-both", 2.0)))
ROW_CELL = ("model", "noise_px", "depth_scale_rms", "camera_rot_deg", "camera_step_rel")
EXTRA_LEVELS_PX = (0.5, 2.0)
CALM = 0.10  # issue 58's bar for a single consistent clip
THRESHOLDS = (0.05, 0.1, 0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--first", type=int, default=0, help="the first scene's index k in its pool")
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--fovs", type=float, nargs="+", default=[60.0], help="fields of view to draw from [deg]")
    parser.add_argument("--depth-scale-rms", type=float, default=0.0,
                        help="also a cell with a per-frame depth scale error of this relative RMS")
    parser.add_argument("--camera-rot-deg", type=float, nargs="+", default=[],
                        help="also cells with each camera turned by a rotation of this RMS per axis [deg]")
    parser.add_argument("--camera-step-rel", type=float, nargs="+", default=[],
                        help="also cells with each camera centre moved by this RMS per axis [median camera steps]")
    parser.add_argument("--models", nargs="+", default=[], choices=sorted(set(NOISE_MODELS) - {"iid-curr", "iid-both"}),
                        help="also these noise models (research.noise) at 0.5 and 2 px")
    parser.add_argument("--perturb", type=float, default=0.0,
                        help="also score the three perturbations at this severity, paired with each cell's noise")
    parser.add_argument("--pool", choices=sorted(RANDOM_POOLS), default="unseen",
                        help="unseen: report-only seeds 7200-7299; fit: FIT's seeds 30-99")
    parser.add_argument("--noise-draw", type=int, default=0,
                        help="K > 0: every cell's noise an independent draw (seed + K * protocol.NOISE_DRAW_STRIDE)")
    parser.add_argument("--back-wall-depth", type=float, default=0.0,
                        help="every scene's back wall this far [depth units; the layers lie at 2-12]: a sky")
    parser.add_argument("--sky-invalid", action="store_true", help="with --back-wall-depth: its depth set to 0")
    parser.add_argument("--spec", type=json.loads, default={},
                        help="SceneSpec fields set on every scene (JSON), e.g. '{\"n_layers\": 0, \"static_spheres\": 0}'")
    parser.add_argument("--focal-scale", type=float, default=1.0, help="every clip's focal lengths this many times the true ones")
    parser.add_argument("--focal-jitter", type=float, default=0.0,
                        help="each frame's focal lengths times its own factor exp(r N(0, 1)), this r")
    parser.add_argument("--one-k", action="store_true", help="with --focal-jitter: every frame's K their median")
    parser.add_argument("--depth-resample", type=float, default=1.0,
                        help="F > 1: each frame's depth shrunk F times (area average) and enlarged bilinearly")
    parser.add_argument("--depth-bits", type=int, default=0,
                        help="N > 0: each clip's inverse depth quantised to N bits over its range")
    parser.add_argument("--depth-offset-rms", type=float, default=0.0,
                        help="r > 0: each frame's depth plus its own offset, r N(0, 1) x the clip's median depth")
    parser.add_argument("--depth-edge-ratio", type=float, default=0.0,
                        help="R > 1: depth invalid on the ramps at edges whose 3 x 3 neighbourhood spans more than R")
    parser.add_argument("--out", help="write one row per clip (CSV)")
    parser.add_argument("--rows", help="print the tables from this CSV (an earlier --out) instead of scoring")
    parser.add_argument("--against", help="rows (CSV) of the same scenes scored otherwise (another tree or config): "
                                          "per cell, clips above 0.10 and detections there -> here")
    args = parser.parse_args()
    cells = CELLS + ((("iid-both", 0.5, args.depth_scale_rms, 0.0, 0.0),) if args.depth_scale_rms > 0 else ())
    cells += tuple(("iid-both", 0.5, 0.0, rot, 0.0) for rot in args.camera_rot_deg)
    cells += tuple(("iid-both", 0.5, 0.0, 0.0, step) for step in args.camera_step_rel)
    builtin = len(cells)
    cells += tuple((model, px, 0.0, 0.0, 0.0) for model in args.models for px in EXTRA_LEVELS_PX)
    rows = rows_scored_or_read(args.rows, args.out, lambda: score_rows(args, cells, builtin), ROW_TEXT, ROW_INTEGERS)
    cells = tuple(dict.fromkeys(cell_of(r) for r in rows))  # as scored or read
    pool = next(name for name, seeds in RANDOM_POOLS.items() if rows[0]["seed"] in seeds)
    print(f"{len({r['scene'] for r in rows})} scenes of the {pool} pool, {sorted({r['tracks'] for r in rows})} tracks, "
          f"fields of view {sorted({r['fov_deg'] for r in rows})}\n")
    print("| noise | clips above 0.10 | largest | median | reward, median | D, median | statuses |")
    print("|---|---|---|---|---|---|---|")
    for noise in cells:
        cell = consistent(rows, noise)
        sgc = np.array([r["sgc"] for r in cell])
        reward, unit = (np.nanmedian([r.get(c, np.nan) for r in cell]) for c in ("reward", "depth_unit"))
        statuses = {s: sum(r["status"] == s for r in cell) for s in sorted({r["status"] for r in cell})}
        print(f"| {cell_label(*noise)} | {int(np.sum(sgc > CALM))} of {len(cell)} | {np.nanmax(sgc):.3f} | "
              f"{np.nanmedian(sgc):.3f} | {reward:.3f} | {unit:.3g} | {statuses} |")
    severity = args.perturb if args.perturb > 0 else max(r["severity"] for r in rows)
    if severity > 0:
        print_detection(rows, cells, severity)
        if "sgc_lo" in rows[0]:
            print_thresholds(rows, cells, severity)
    if args.against:
        print_against(rows, read_rows(args.against, ROW_TEXT, ROW_INTEGERS), args.against, cells, severity)


ROW_TEXT, ROW_INTEGERS = ("model", "kind", "status", "reason", "camera_motion"), ("scene", "seed", "tracks")


def score_rows(args, cells, builtin: int) -> list[dict]:
    """One row per (scene, noise cell, variant): the consistent clip and its perturbations."""
    rows = []
    for k in range(args.first, args.first + args.scenes):
        scene = random_scene(k, args.fovs, args.pool)
        if args.back_wall_depth > 0 or args.spec:
            extra = {"back_wall_depth": args.back_wall_depth} if args.back_wall_depth > 0 else {}
            scene = dataclasses.replace(scene, spec={**scene.spec, **extra, **args.spec})
        seed, spec = scene.seed, scene.spec
        started = time.perf_counter()
        clean = scene.clip(args.tracks)
        if args.sky_invalid:
            clean = sky_invalid(clean)
        if args.focal_scale != 1.0 or args.focal_jitter > 0:
            factors = args.focal_scale * np.exp(args.focal_jitter * np.random.default_rng(seed).standard_normal(clean.n_frames))
            clean = with_focal_scale(clean, np.full_like(factors, np.median(factors)) if args.one_k else factors)
        variants = [("", 0.0, clean)] + [(kind, args.perturb, perturb_clip(clean, kind, args.perturb, seed=seed))
                                         for kind in (PERTURBATIONS if args.perturb > 0 else ())]
        variants = [(kind, severity, estimator_depth(clip, args.depth_resample, args.depth_bits, args.depth_edge_ratio))
                    for kind, severity, clip in variants]
        if args.depth_offset_rms > 0:
            offsets = NoiseModel(depth_offset_rel=args.depth_offset_rms)
            variants = [(kind, severity, add_noise(clip, offsets, seed)) for kind, severity, clip in variants]
        models = [NOISE_MODELS[model].replace(px=px, depth_scale_rel=scale, camera_rot_deg=rot, camera_step_rel=step)
                  for model, px, scale, rot, step in cells]
        jobs = [(j, kind, severity, add_noise(exact, noise, seed=noise_seed(seed, j, builtin, args.noise_draw)))
                for j, noise in enumerate(models) for kind, severity, exact in variants]
        result = score_batch([clip for *_, clip in jobs])
        for (j, kind, severity, _), scored, reward in zip(jobs, result.clips, result.rewards()["reward"]):
            rows.append(dict(scene=k, seed=seed, **spec, tracks=args.tracks, **dict(zip(ROW_CELL, cells[j])), kind=kind,
                             severity=severity, status=scored.status, reason=scored.reason, sgc=scored.sgc,
                             sgc_lo=scored.sgc_lo, sgc_hi=scored.sgc_hi, evidence=scored.evidence, scale=scored.scale,
                             sky_invalid=int(args.sky_invalid), focal_scale=args.focal_scale,
                             focal_jitter=args.focal_jitter, one_k=int(args.one_k), depth_resample=args.depth_resample,
                             depth_bits=args.depth_bits, depth_offset_rms=args.depth_offset_rms,
                             depth_unit=scored.depth_unit,
                             reward=float(reward),
                             **scored.components))
        print(f"{scene.name} {spec}: " + " ".join(f"{r['sgc']:.3f} ({r['status']})" for r in rows[-len(jobs):]
                                                    if not r["kind"])
              + f" [{time.perf_counter() - started:.0f} s]", file=sys.stderr, flush=True)
    return rows


def sky_invalid(clip):
    """The clip with its back wall's depth (beyond twice the layers' farthest) set to 0, as a sky mask."""
    beyond = clip.depth > 2.0 * clip.meta["depth_range"][1]
    return dataclasses.replace(clip, depth=np.where(beyond, 0.0, clip.depth).astype(clip.depth.dtype))


def estimator_depth(clip, resample: float, bits: int, edge_ratio: float = 0.0):
    """The clip's depth as a network at 1/``resample`` of the frame's size and an image of ``bits``
    bits of inverse depth over the clip's range would leave it (either off at 1 and 0), then with the
    ramps at its edges spanning more than ``edge_ratio`` invalid (off at 0; ``adapters.leave_out_depth_ramps``)."""
    if resample <= 1 and bits <= 0 and edge_ratio <= 1:
        return clip
    depth = clip.depth.astype(np.float32)
    if resample > 1:
        depth = enlarged_depth(depth, resample)
    if bits > 0:
        valid = depth > 0
        inverse = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0)
        low, high = inverse[valid].min(), inverse[valid].max()
        levels = 2 ** bits - 1
        stored = np.round((inverse - low) / (high - low) * levels) / levels * (high - low) + low
        depth = np.where(valid, 1.0 / stored, 0.0).astype(np.float32)
    if edge_ratio > 1:
        depth = without_ramps(depth, edge_ratio)[0]
    return dataclasses.replace(clip, depth=depth.astype(clip.depth.dtype))


def with_focal_scale(clip, factors: np.ndarray):
    """The clip with fx, fy of frame t's K multiplied by ``factors[t]`` (principal point kept)."""
    K = np.broadcast_to(clip.K, (clip.n_frames, 3, 3)).astype(np.float64)  # copied
    K[:, 0, 0] *= factors
    K[:, 1, 1] *= factors
    return dataclasses.replace(clip, K=K.astype(clip.K.dtype))


def cell_of(row: dict) -> tuple:
    """A row's noise cell, ROW_CELL's values (rows written before the camera cells: none)."""
    return tuple(row.get(column, 0.0) for column in ROW_CELL)


def consistent(rows: list[dict], cell) -> list[dict]:
    """The consistent clips of a noise cell (ROW_CELL's values)."""
    return [r for r in rows if cell_of(r) == cell and r["kind"] == ""]


def detections(rows: list[dict], cell, severity: float) -> tuple[dict[str, int], int]:
    """(per perturbation, the scenes of a noise cell where it scores above its consistent twin; the
    cell's scenes)."""
    keyed = [dict(r, cell=r["scene"]) for r in rows if cell_of(r) == cell]
    scenes = len({r["scene"] for r in keyed})
    shares = detection_table(keyed)
    return {kind: round(shares.get((kind, severity), 0.0) * scenes) for kind in PERTURBATIONS}, scenes


def print_against(rows: list[dict], other: list[dict], path: str, cells, severity: float) -> None:
    """Per noise cell, the consistent clips above 0.10 and the detections at ``severity`` in
    ``other`` -> in these rows, their sums, and the largest fall of one cell's perturbation."""
    shared = {r["scene"] for r in rows} & {r["scene"] for r in other}
    rows, other = ([r for r in x if r["scene"] in shared] for x in (rows, other))
    print(f"\nAgainst {path}: {len(shared)} scenes in both; there -> here\n")
    print("| noise | consistent clips above 0.10 | " + " | ".join(PERTURBATIONS) + " |")
    print("|---|---|" + "---|" * len(PERTURBATIONS))
    above, seen, falls = np.zeros(2, int), np.zeros(2, int), []
    for cell in cells:
        calm = [int(sum(r["sgc"] > CALM for r in consistent(x, cell))) for x in (other, rows)]
        there, here = (detections(x, cell, severity)[0] for x in (other, rows))
        above, seen = above + calm, seen + [sum(there.values()), sum(here.values())]
        falls += [(here[kind] - there[kind], cell_label(*cell), kind) for kind in PERTURBATIONS]
        print(f"| {cell_label(*cell)} | {calm[0]} -> {calm[1]} | "
              + " | ".join(f"{there[kind]} -> {here[kind]}" for kind in PERTURBATIONS) + " |")
    summary = f"\nconsistent clips above 0.10: {above[0]} -> {above[1]}"
    if severity > 0:
        fall = min(falls)
        summary += (f"; detections at {severity}: {seen[0]} -> {seen[1]} of {len(shared) * len(cells) * len(PERTURBATIONS)}; "
                    f"the largest fall of one cell's perturbation: {fall[0]} ({fall[1]}, {fall[2]})")
    print(summary)


def noise_seed(scene_seed: int, cell: int, builtin: int, draw: int = 0) -> int:
    """The noise draw of a scene's cell: the built-in cells' as before (scene seed * 10 + index), each
    ``--models`` cell its own (scene seed * 100 + 10 + its index among them); ``draw`` > 0 an
    independent one (+ draw * ``protocol.NOISE_DRAW_STRIDE``, as ``protocol.Cell.draw``)."""
    own = scene_seed * 10 + cell if cell < builtin else scene_seed * 100 + 10 + cell - builtin
    return draw * NOISE_DRAW_STRIDE + own


def cell_label(model: str, px: float, scale: float, rot: float = 0.0, step: float = 0.0) -> str:
    return (f"{model} {px} px" + (f", depth scale {scale:.0%} a frame" if scale else "")
            + (f", cameras turned {rot} deg" if rot else "") + (f", camera centres moved {step} steps" if step else ""))


def print_thresholds(rows: list[dict], cells, severity: float) -> None:
    """Per noise cell, unpaired: the share of consistent clips and of each perturbation whose SGC,
    and whose ``sgc_lo``, lies above each of THRESHOLDS (what a corpus user's cut would flag)."""
    print(f"\nAbove a threshold, unpaired (consistent; {', '.join(PERTURBATIONS)} at {severity}), by sgc and by sgc_lo\n")
    print("| noise | " + " | ".join(f"sgc > {t}" for t in THRESHOLDS) + " | " + " | ".join(f"sgc_lo > {t}" for t in THRESHOLDS) + " |")
    print("|---|" + "---|" * (2 * len(THRESHOLDS)))
    for cell in cells:
        of_cell = [r for r in rows if cell_of(r) == cell]
        groups = [[r for r in of_cell if r["kind"] == kind and r["severity"] in (0.0, severity)] for kind in ("", *PERTURBATIONS)]
        shares = [" / ".join(f"{np.mean([r[column] > t for r in group]):.0%}" for group in groups)
                  for column in ("sgc", "sgc_lo") for t in THRESHOLDS]
        print(f"| {cell_label(*cell)} | " + " | ".join(shares) + " |")


def print_detection(rows: list[dict], cells, severity: float) -> None:
    """Per noise cell, the share of scenes where each perturbation scores above its consistent twin."""
    print(f"\nDetection at severity {severity} (paired: the twin carries the same noise draw)\n")
    print("| noise | " + " | ".join(PERTURBATIONS) + " |")
    print("|---|" + "---|" * len(PERTURBATIONS))
    for cell in cells:
        hits, scenes = detections(rows, cell, severity)
        print(f"| {cell_label(*cell)} | " + " | ".join(f"{hits[kind] / scenes:.0%} of {scenes}" for kind in PERTURBATIONS)
              + " |")


if __name__ == "__main__":
    main()

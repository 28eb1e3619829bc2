"""Real footage of a rigid world (issues 41, 58): the clips of ``../shared/realdata/`` (static scenes
with ground-truth depth and cameras and real tracks; its README says how they were made) under the
default config and calibration.

    python bench/realdata.py [--dir ../shared/realdata] [--engine jax] [--out realdata.csv] [--no-ladders]
                             [--config FILE] [--regions N] [--line-ratio 0.05] [--depth-edge-ratio 1.2]
                             [--camera-rot-deg 0.3] [--camera-step-rel 0.1] [--radial-k1 -0.1] [--letterbox 0.1]
                             [--overlay 0.15 0.08] [--long-range]
                             [--noise-models iid-curr iid-both correlated depth outliers --noise-levels 0.5 1 2]

Prints

1. per clean clip: SGC, its interval, each pose component against its noise floor, the pose jitter
   of the local rotations and translations (sgc_jax.research.pose_jitter: how much two layers'
   relative pose changes between pairs against the floors' noise), the depth error and the
   tracks' distance to the ground-truth motion (median and 95th percentile over the usable tracks,
   px; sgc_jax.research.ground_truth), its evidence and reward (docs/semantics.md §3.11, §9.4),
   sorted by that distance (the bars: SGC <= 0.05 where the 95th percentile is within 2 px);
2. the paper's perturbations (§4.3 protocol: warp, squeeze, depth_warp at severities 0.25, 0.5, 1)
   on every clip: SGC and reward by severity, 0 the clean clip (the bars: every ladder's SGC rises
   strictly, its reward falls strictly);
3. with ``--regions N``: per clean clip, the N accepted local poses farthest from the camera's
   rotation, with their tracks' distance to the ground-truth motion (what a pose there measured:
   the world, or the tracker's failure; sgc_jax.research.ground_truth.region_motion_errors).

``--line-ratio R`` scores every clip (and its ladders) with the tracks that start on a line left
out first (sgc_jax.adapters.leave_out_line_tracks, docs/semantics.md §1.7); ``--depth-edge-ratio R``
with the depth on the ramps at edges spanning more than R left out, the ladders' after their
perturbation (sgc_jax.adapters.leave_out_depth_ramps, §3.6 "Smooth depth edges"). ``--camera-rot-deg a``
and ``--camera-step-rel b`` score every clip (and its ladders) with errors on its cameras, as a pose
estimator's: each turned about its centre by a rotation of RMS a degrees per axis and its centre
moved by b median camera steps per axis, independently per frame (sgc_jax.research.noise, seeded by
the clip's place); the tracks' distance to the ground-truth motion is still the exact cameras'.
``--radial-k1 k`` scores every clip (and its ladders) as a lens with radial distortion k1 images it,
its K still the pinhole's (sgc_jax.research.noise.radially_distorted); the tracks' distance to the
ground-truth motion is their undistorted one's.
``--letterbox s`` gives every clip (and its ladders) letterbox bars of s of its rows at the top and
bottom, at its median depth, static and without tracks (sgc_jax.research.noise.letterboxed), as a
depth network and a motion segmenter leave a letterboxed video's black bars.
``--overlay w h`` gives every clip (and its ladders) an overlay of w x h of the frame in its
bottom-right corner, as a watermark: tracks that start on it stay put, one depth, static
(sgc_jax.research.noise.overlaid).

``--long-range`` scores every clip (and its ladders) with long-range tracks in place of its own: its
first grid followed through the clip by the clips' own LK, each lost track queried again at that
slot's grid point (bench/rigid_changes.py, ``lk-long-reseeded``), so errors lie at both ends of a
pair and drift along the clip, as a tracker queried once gives them; the tracks' distance to the
ground-truth motion is then each pair's, from its frame i-1 positions as tracked.

``--noise-models M ... --noise-levels PX ...`` also scores every clip under the validation
protocol's estimator errors on top of its own tracker's (sgc_jax.research.noise.NOISE_MODELS,
docs/semantics.md §7.4; each model at each level, one draw seeded by the clip's place), with the
perturbations at severity 0.25 under the same draw (perturbed first, then the errors, as the
protocol's cells), and prints per model and level: the clean clips' SGC against their clips as
read, and how many clips each perturbation scores above its twin in SGC and below it in reward.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from sgc_jax import COMPONENTS, SGCConfig, load_clip, score_batch
from sgc_jax.adapters import leave_out_depth_ramps, leave_out_line_tracks
from sgc_jax.research.ground_truth import motion_errors, region_motion_errors
from sgc_jax.research.noise import NOISE_MODELS, NoiseModel, add_noise, letterboxed, overlaid, radially_distorted
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.pose_jitter import pose_jitter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rigid_changes import long_range  # noqa: E402

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"
LADDER_SEVERITIES = (0.25, 0.5, 1.0)
NOISY_SEVERITY = 0.25  # the protocol's detection bar's severity (issue 58)


def print_clean(clips, result, exact) -> None:
    """``exact``: the clips as read, whose cameras give the ground-truth motion (``clips`` may carry
    camera errors)."""
    print("| clip | tracks to GT motion, median / p95 px | SGC | 90 % interval | "
          + " | ".join(f"{k} / floor" for k in POSE_COMPONENTS) + " | pose jitter, rot / trans | depth_error % "
          "| tracks per pair | evidence | reward |")
    print("|---|---|---|---|" + "---|" * (len(POSE_COMPONENTS) + 5))
    rows = []
    rewards = result.rewards()["reward"]
    for clip, scored, reward, truth in zip(clips, result.clips, rewards, exact):
        distance = motion_errors(truth)
        rows.append((np.percentile(distance, 95), clip, scored, np.median(distance), reward))
    for p95, clip, scored, median, reward in sorted(rows, key=lambda r: r[0]):
        ratios = [scored.components[k] / scored.floors[f"{k}_floor"] for k in POSE_COMPONENTS]
        tracks = int(scored.pairs.n_tracks.mean()) if scored.pairs is not None else 0
        jitter = pose_jitter(scored.pairs) if scored.pairs is not None else None
        print(f"| {clip.clip_id} | {median:.2f} / {p95:.2f} | {scored.sgc:.3f} | "
              f"{scored.sgc_lo:.3f}-{scored.sgc_hi:.3f} | " + " | ".join(f"{r:.2f}" for r in ratios)
              + (f" | {jitter.rot:.2f} / {jitter.trans:.2f}" if jitter else " | -")
              + f" | {scored.components['depth_error']:.2f} | {tracks} | {scored.evidence:.2f} | {reward:.3f} |")


def print_regions(clips, result, config: SGCConfig, count: int) -> None:
    print(f"\nThe {count} local poses of each clean clip farthest from the camera's rotation")
    print("| clip | pair | region | members | rotation off the camera's, deg | its tracks to GT motion, median px "
          "| share beyond 3 px |")
    print("|---|---|---|---|---|---|---|")
    for clip, scored in zip(clips, result.clips):
        records = sorted(region_motion_errors(clip, scored.pairs, config), key=lambda r: -r["deg_off"])
        for r in records[:count]:
            print(f"| {clip.clip_id} | {r['pair']} | {r['region']} | {r['members']} | {r['deg_off']:.2f} | "
                  f"{r['median_px']:.2f} | {r['share_off']:.2f} |")


def print_ladders(clips, clean, engine: str, config: SGCConfig, prepare=lambda clip: clip) -> None:
    print("\nPerturbation ladders: SGC (reward) at severity 0 (clean), " + ", ".join(f"{s:g}" for s in LADDER_SEVERITIES))
    print("| clip | perturbation | " + " | ".join(f"{s:g}" for s in (0.0, *LADDER_SEVERITIES))
          + " | SGC rises strictly | reward falls strictly |")
    print("|---|---|" + "---|" * (len(LADDER_SEVERITIES) + 3))
    variants = [prepare(perturb_clip(clip, kind, s, seed=0))
                for clip in clips for kind in PERTURBATIONS for s in LADDER_SEVERITIES]
    result = score_batch(variants, engine=engine, config=config, progress=False)
    scored = iter(zip(result.clips, result.rewards()["reward"]))  # in the order made
    rising = falling = 0
    for clip, (clean_sgc, clean_reward) in zip(clips, clean):
        for kind in PERTURBATIONS:
            steps = [next(scored) for _ in LADDER_SEVERITIES]
            sgc = np.array([clean_sgc, *(c.sgc for c, _ in steps)])
            reward = np.array([clean_reward, *(r for _, r in steps)])
            rises, falls = bool(np.all(np.diff(sgc) > 0)), bool(np.all(np.diff(reward) < 0))
            rising, falling = rising + rises, falling + falls
            print(f"| {clip.clip_id} | {kind} | " + " | ".join(f"{v:.3f} ({r:.3f})" for v, r in zip(sgc, reward))
                  + f" | {'yes' if rises else 'NO'} | {'yes' if falls else 'NO'} |")
    n = len(clips) * len(PERTURBATIONS)
    print(f"\n{rising} of {n} ladders rise strictly in SGC; {falling} of {n} fall strictly in reward")


def print_noise(clips, clean_sgc, models, levels, engine: str, config: SGCConfig) -> None:
    """The clips under each protocol noise model and level (module docstring); ``clean_sgc``: the
    clips' SGC as read."""
    kinds = ("", *PERTURBATIONS)  # "": the clip itself, the perturbations' twin
    cells = [(model, px) for model in models for px in levels]
    variants = []
    for model, px in cells:
        errors = NOISE_MODELS[model].replace(px=px)
        for k, clip in enumerate(clips):
            for kind in kinds:
                base = perturb_clip(clip, kind, NOISY_SEVERITY, seed=0) if kind else clip
                variants.append(add_noise(base, errors, seed=k))
    result = score_batch(variants, engine=engine, config=config, progress=False)
    sgc = np.array([c.sgc for c in result.clips]).reshape(len(cells), len(clips), len(kinds))
    reward = np.asarray(result.rewards()["reward"]).reshape(sgc.shape)
    print(f"\nThe clips under the protocol's estimator errors on top of their own tracker's; perturbations at "
          f"{NOISY_SEVERITY:g} under the same draw (of {len(clips)} clips)")
    print("| noise model | px | SGC minus as read: median (range) | largest SGC | reward, median | "
          + " | ".join(f"{k} above / reward below" for k in PERTURBATIONS) + " |")
    print("|---|---|---|---|---|" + "---|" * len(PERTURBATIONS))
    for (model, px), cell_sgc, cell_reward in zip(cells, sgc, reward):
        rise = cell_sgc[:, 0] - clean_sgc
        detected = [f"{int(np.sum(cell_sgc[:, j] > cell_sgc[:, 0]))} / {int(np.sum(cell_reward[:, j] < cell_reward[:, 0]))}"
                    for j in range(1, len(kinds))]
        print(f"| {model} | {px:g} | {np.median(rise):+.3f} ({rise.min():+.3f} to {rise.max():+.3f}) | "
              f"{cell_sgc[:, 0].max():.3f} | {np.median(cell_reward[:, 0]):.3f} | " + " | ".join(detected) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--engine", default="jax")
    parser.add_argument("--out", default=None, help="CSV of the clean clips' rows")
    parser.add_argument("--no-ladders", action="store_true")
    parser.add_argument("--config", default=None, help="a config file (JSON) for the score (default: SGCConfig())")
    parser.add_argument("--line-ratio", type=float, default=None,
                        help="leave out the tracks that start on a line (structure ratio below this) first")
    parser.add_argument("--depth-edge-ratio", type=float, default=None,
                        help="score every clip (its ladders after their perturbation) with the depth on the ramps at "
                             "edges spanning more than this ratio left out (sgc_jax.adapters.leave_out_depth_ramps)")
    parser.add_argument("--regions", type=int, default=0, help="also print each clean clip's N local poses "
                                                               "farthest from the camera's rotation")
    parser.add_argument("--camera-rot-deg", type=float, default=0.0,
                        help="turn each camera by a rotation of this RMS per axis [deg] before scoring")
    parser.add_argument("--camera-step-rel", type=float, default=0.0,
                        help="move each camera centre by this RMS per axis [median camera steps] before scoring")
    parser.add_argument("--radial-k1", type=float, default=0.0,
                        help="see every clip through a lens of this radial distortion (its K still a pinhole's)")
    parser.add_argument("--letterbox", type=float, default=0.0,
                        help="give every clip letterbox bars of this share of its rows at top and bottom (one depth, "
                             "static, no tracks)")
    parser.add_argument("--overlay", type=float, nargs=2, default=None, metavar=("W", "H"),
                        help="give every clip an overlay of W x H of the frame in its corner (tracks on it stay put, "
                             "one depth, static)")
    parser.add_argument("--long-range", action="store_true",
                        help="score every clip with long-range tracks from its frames in place of its own")
    parser.add_argument("--noise-models", nargs="*", default=[], choices=sorted(NOISE_MODELS),
                        help="also score the clips under these protocol noise models (docs/semantics.md §7.4)")
    parser.add_argument("--noise-levels", nargs="*", type=float, default=[0.5, 1.0, 2.0],
                        help="the track error levels of --noise-models [px RMS per coordinate]")
    args = parser.parse_args()
    config = SGCConfig.from_dict(json.loads(Path(args.config).read_text())) if args.config else SGCConfig()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    clips = [load_clip(str(p)) for p in paths]
    if args.long_range:
        clips = [long_range(clip, reseed=True) for clip in clips]
    if args.line_ratio is not None:
        clips = [leave_out_line_tracks(clip, args.line_ratio) for clip in clips]
    exact = clips
    def prepare(clip):
        return leave_out_depth_ramps(clip, args.depth_edge_ratio) if args.depth_edge_ratio else clip

    if args.camera_rot_deg > 0 or args.camera_step_rel > 0:
        cameras = NoiseModel(camera_rot_deg=args.camera_rot_deg, camera_step_rel=args.camera_step_rel)
        clips = [add_noise(clip, cameras, seed=k) for k, clip in enumerate(clips)]
    if args.radial_k1:
        clips = [radially_distorted(clip, args.radial_k1) for clip in clips]
    if args.letterbox:
        clips = [letterboxed(clip, args.letterbox) for clip in clips]
    if args.overlay:
        clips = [overlaid(clip, *args.overlay) for clip in clips]
    result = score_batch([prepare(clip) for clip in clips], engine=args.engine, config=config, progress=False)
    print_clean(clips, result, exact)
    if args.out:
        result.to_pandas().to_csv(args.out, index=False)
    if args.regions:
        print_regions(clips, result, config, args.regions)
    if args.noise_models:
        print_noise(clips, np.array([c.sgc for c in result.clips]), args.noise_models, args.noise_levels,
                    args.engine, config)
    if not args.no_ladders:
        print_ladders(clips, list(zip([c.sgc for c in result.clips], result.rewards()["reward"])), args.engine,
                      config, prepare)


if __name__ == "__main__":
    main()

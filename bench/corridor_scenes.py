"""A scene family written apart from research.synth, for reports only: a camera walking down a
corridor (docs/semantics.md §7.4, "A corridor").

    python bench/corridor_scenes.py [--scenes 6] [--tracks 200 1000 4096] [--levels 0.5 2]
                                    [--models iid-curr iid-both correlated depth outliers]
                                    [--perturb 0.25] [--config '{"partition": "grid"}']
                                    [--out rows.csv] [--rows rows.csv] [--ladders] [--street]
                                    [--tracked 6]

Every layout of the protocol's splits and pools (research.synth) stands in front of the camera:
a back wall, rectangles at set depths, spheres, at most a ground. Here every surface but the end
wall is seen obliquely, so depth runs continuously from the camera's feet to the end of the
corridor: two side walls, a floor and a ceiling (the corridor 3-5 units wide, 2.4-3.2 high and
15-30 long), the end wall, and four boxes standing on the floor along the walls. The camera walks
0.25 units a frame down the corridor (about 3 % of the median depth), swaying sideways and turning
1° a frame. Depth is ray-cast at pixel centres, tracks are drawn uniformly over frame i−1 and
projected through the exact geometry into frame i (visible where frame i's depth does not hide
them), as the clip format defines (docs/semantics.md §1.1); NumPy only, every draw from the scene's
seed (``CORRIDOR_SEEDS``, which no split or pool uses). Nothing is chosen on these scenes.

Noise: the protocol's models (research.noise, named as there) at each ``--levels`` px, one draw a
cell, the perturbed clips given their consistent twin's draw (paired, as bench/validation.py).
Inconsistencies: the paper's three perturbations at ``--perturb`` (made on the exact clip), and an
unmasked mover (the nearest box walks across the corridor at 0.08 units a frame) against its
masked twin. Prints, per noise model and track count, the consistent clips' median at each level
and its rise, the largest and how many lie above 0.10, the statuses; the share of cells where each
inconsistency scores above its twin; and, on the exact clips, the depth error and its part that
the depth check's rounding to the nearest pixel makes on oblique surfaces (§3.6 step 2): the mean
relative error of frame i−1's warped points against frame i's depth at the nearest pixel, and
against frame i's inverse depth interpolated bilinearly at the point's own position, over points
whose four neighbours lie on one surface. ``--config``: SGCConfig fields (JSON) to score with.
``--ladders``: also each scene's perturbation ladders (severities 0.1, 0.25, 0.5, 1; 1,000 tracks,
iid-both 1 px, paired): how many rise strictly in SGC and fall strictly in reward (issue 59's bar).
``--street``: the same scenes as streets: no ceiling, the walls and the end wall ending at the same
height, sky above them (depth 0, invalid; its tracks points at infinity, moved by the camera's
rotation alone, as a tracker follows clouds). ``--tracked STRIDE``: every surface is painted with
value noise (``TEXTURE_OCTAVES``) into RGB frames, and each scene's clean clip, warp and depth_warp
at 0.25 and 0.5 and the mover with its masked twin are retracked on their own frames by pyramidal
LK from a grid of STRIDE px (bench/track_density.py): a real tracker's errors on a known world.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from sgc_jax.research.corridor import CORRIDOR_SEEDS, MASK_MARGIN_PX, Corridor, CorridorSpec, family

LADDER_SEVERITIES = (0.1, 0.25, 0.5, 1.0)


def rounding_part(clip) -> tuple[float, float]:
    """Under the exact cameras, every valid pixel of frame i−1 warped into frame i: the mean relative
    error [%] against frame i's depth at the nearest pixel (§3.6 step 2) and against its inverse
    depth interpolated bilinearly at the point's own position, over points whose four neighbours lie
    within 5 % of one another and whose nearest pixel within 5 % of the point (one surface)."""
    depth, K = clip.depth.astype(float), np.broadcast_to(clip.K, (clip.n_frames, 3, 3)).astype(float)
    R, t = clip.R_wc.astype(float), clip.t_wc.astype(float)
    H, W = clip.image_size
    rows, cols = np.mgrid[0:H, 0:W]
    nearest, interpolated = [], []
    for i in range(1, clip.n_frames):
        valid = depth[i - 1] > 0
        pixels = np.stack([cols[valid], rows[valid], np.ones(valid.sum())])
        world = R[i - 1].T @ (np.linalg.inv(K[i - 1]) @ pixels * depth[i - 1][valid] - t[i - 1][:, None])
        camera = R[i] @ world + t[i][:, None]
        z = camera[2]
        u, v = (K[i] @ camera)[:2] / np.where(z > 1e-5, z, np.nan)
        keep = (z > 1e-5) & (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
        u, v, z = u[keep], v[keep], z[keep]
        at_nearest = depth[i][np.floor(v + 0.5).astype(int), np.floor(u + 0.5).astype(int)]
        u0, v0 = np.minimum(np.floor(u).astype(int), W - 2), np.minimum(np.floor(v).astype(int), H - 2)
        fu, fv = u - u0, v - v0
        four = np.stack([depth[i][v0, u0], depth[i][v0, u0 + 1], depth[i][v0 + 1, u0], depth[i][v0 + 1, u0 + 1]])
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = ((1 - fu) * (1 - fv) / four[0] + fu * (1 - fv) / four[1] + (1 - fu) * fv / four[2]
                       + fu * fv / four[3])
            surface = (four.min(0) > 0) & (four.max(0) < 1.05 * four.min(0)) & (np.abs(at_nearest / z - 1) < 0.05)
        nearest.append(np.abs(z - at_nearest)[surface] / at_nearest[surface])
        interpolated.append(np.abs(z * inverse - 1)[surface])
    return 100 * float(np.concatenate(nearest).mean()), 100 * float(np.concatenate(interpolated).mean())


def score_rows(args) -> list[dict]:
    """One row per clip: scene, tracks, noise cell, kind ("" consistent, a perturbation, "mover",
    "mover-masked"), severity, the score's outputs and the tracks on the mover."""
    from sgc_jax import score_batch
    from sgc_jax.research.noise import NOISE_MODELS, add_noise
    from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
    from sgc_jax.research.protocol import tracks_on_mover

    cells = list(itertools.product(args.models, args.levels))
    rows, clips = [], []
    for k, n_tracks in itertools.product(range(args.scenes), args.tracks):
        seed, spec = CORRIDOR_SEEDS[k], CorridorSpec(n_tracks=n_tracks, sky=args.street)
        still, moving = Corridor(seed, spec, moving=False), Corridor(seed, spec, moving=True)
        name = f"{family(args.street)}-{k}"
        clean = still.clip(masked=False, clip_id=f"{name}-{n_tracks}")
        exact = [(clean, "", 0.0)] + [(perturb_clip(clean, kind, args.perturb, seed=seed), kind, args.perturb)
                                      for kind in PERTURBATIONS]
        exact += [(moving.clip(masked=True, clip_id=f"{name}-{n_tracks}-masked"), "mover-masked", 0.0),
                  (moving.clip(masked=False, clip_id=f"{name}-{n_tracks}-mover"), "mover", 1.0)]
        on_mover = tracks_on_mover(exact[-2][0], 0.0, MASK_MARGIN_PX)
        for c, (model, px) in enumerate(cells):
            noise = NOISE_MODELS[model].replace(px=px)
            for clip, kind, severity in exact:
                clips.append(add_noise(clip, noise, seed * 100 + c))
                rows.append(dict(scene=name, tracks=n_tracks, model=model, noise_px=px, kind=kind, severity=severity,
                                 tracks_on_mover=on_mover, cell=f"{name}/{n_tracks}/{model}/{px}"))
    result = score_batch(clips, config=args.score_config)
    rewards = result.rewards()["reward"]
    for row, clip, reward in zip(rows, result.clips, rewards):
        row.update(sgc=clip.sgc, status=clip.status, evidence=clip.evidence, depth_error=clip.components["depth_error"],
                   reward=float(reward))
    return rows


def print_tables(rows: list[dict]) -> None:
    import pandas as pd

    from sgc_jax.research.protocol import detection_table

    frame = pd.DataFrame(rows)
    consistent = frame[frame.kind == ""]
    levels = sorted(consistent.noise_px.unique())
    print("consistent clips: median SGC by level, the rise from the first to the last, the largest, above 0.10")
    print("| model | tracks | " + " | ".join(f"{px} px" for px in levels) + " | rise | largest | above 0.10 | statuses |")
    print("|---|---|" + "---|" * (len(levels) + 4))
    for (model, tracks), cell in consistent.groupby(["model", "tracks"], sort=False):
        medians = [cell[cell.noise_px == px].sgc.median() for px in levels]
        statuses = ", ".join(f"{s} {n}" for s, n in cell.status.value_counts().items())
        print(f"| {model} | {tracks} | " + " | ".join(f"{m:.3f}" for m in medians)
              + f" | {medians[-1] - medians[0]:+.3f} | {cell.sgc.max():.3f} | {(cell.sgc > 0.10).sum()} of {len(cell)}"
              f" | {statuses} |")
    print("\nshare of cells where each inconsistency scores above its consistent twin")
    for model, of_model in frame.groupby("model", sort=False):
        shares = detection_table(of_model.to_dict("records"))
        print(f"{model}: " + ", ".join(f"{kind} {severity:g} {share:.0%}" for (kind, severity), share in shares.items()))
    movers = frame[frame.kind == "mover"].groupby("scene").tracks_on_mover.median()
    print("\ntracks on the mover per pair, by scene (median over track counts):",
          ", ".join(f"{scene} {n:.0f}" for scene, n in movers.items()))
    rewards = frame.groupby("kind").reward.median()
    print("median reward by kind:", ", ".join(f"{kind or 'consistent'} {r:.3f}" for kind, r in rewards.items()))


def print_ladders(scenes: int, config, sky: bool) -> None:
    from sgc_jax import score_batch
    from sgc_jax.research.noise import NOISE_MODELS, add_noise
    from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip

    noise = NOISE_MODELS["iid-both"].replace(px=1.0)
    ladders, clips = [], []
    for k in range(scenes):
        seed = CORRIDOR_SEEDS[k]
        clean = Corridor(seed, CorridorSpec(sky=sky), moving=False).clip(False, f"{family(sky)}-{k}")
        for kind in PERTURBATIONS:
            ladders.append((f"{family(sky)}-{k}", kind))
            clips += [add_noise(clean, noise, seed)] + [add_noise(perturb_clip(clean, kind, s, seed=seed), noise, seed)
                                                        for s in LADDER_SEVERITIES]
    result = score_batch(clips, config=config)
    sgc = np.array([c.sgc for c in result.clips]).reshape(len(ladders), -1)
    reward = result.rewards()["reward"].reshape(len(ladders), -1)
    print("\nladders (iid-both 1 px, 1,000 tracks): SGC (reward) at severity 0, " + ", ".join(map(str, LADDER_SEVERITIES)))
    for (scene, kind), scores, rewards in zip(ladders, sgc, reward):
        print(f"{scene} {kind}: " + ", ".join(f"{a:.3f} ({b:.3f})" for a, b in zip(scores, rewards)))
    rising, falling = (np.diff(sgc) > 0).all(1).sum(), (np.diff(reward) < 0).all(1).sum()
    print(f"{rising} of {len(ladders)} ladders rise strictly in SGC; {falling} of {len(ladders)} fall strictly in reward")
    for (scene, kind), scores in zip(ladders, sgc):
        if not (np.diff(scores) > 0).all():
            steps = [f"{a:g} -> {b:g}" for a, b, d in zip((0,) + LADDER_SEVERITIES, LADDER_SEVERITIES, np.diff(scores))
                     if d <= 0]
            print(f"  {scene} {kind} does not rise at {', '.join(steps)} (by {np.diff(scores).min():+.1e})")


def print_tracked(scenes: int, config, sky: bool, stride: int) -> None:
    """Each scene's clean clip, warp and depth_warp at 0.25 and 0.5 (their frames remapped with
    them) and the mover with its masked twin, every one retracked on its own frames by pyramidal
    LK from a grid of ``stride`` px (bench/track_density.py: 21 px windows, the forward-backward
    check under 0.5 px): a real tracker's errors on a known world, in place of a noise model."""
    import sys

    import pandas as pd

    from sgc_jax import score_batch
    from sgc_jax.research.ground_truth import motion_errors
    from sgc_jax.research.perturb import perturb_clip
    from sgc_jax.research.protocol import detection_table

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from track_density import grid_tracks

    rows, clips = [], []
    for k in range(scenes):
        seed, name = CORRIDOR_SEEDS[k], f"{family(sky)}-{k}"
        still, moving = (Corridor(seed, CorridorSpec(sky=sky), moving=m) for m in (False, True))
        clean = still.clip(False, name, with_frames=True)
        variants = [(clean, "", 0.0)] + [(perturb_clip(clean, kind, s, seed=seed), kind, s)
                                         for kind in ("warp", "depth_warp") for s in (0.25, 0.5)]
        variants += [(moving.clip(True, f"{name}-masked", with_frames=True), "mover-masked", 0.0),
                     (moving.clip(False, f"{name}-mover", with_frames=True), "mover", 1.0)]
        for clip, kind, severity in variants:
            clips.append(grid_tracks(clip, stride))
            rows.append(dict(cell=name, kind=kind, severity=severity))
    result = score_batch(clips, config=config)
    rewards = result.rewards()["reward"]
    for row, clip, scored, reward in zip(rows, clips, result.clips, rewards):
        row.update(sgc=scored.sgc, reward=float(reward), status=scored.status,
                   gt_p95=np.percentile(motion_errors(clip), 95) if row["kind"] == "" else np.nan)
    frame = pd.DataFrame(rows)
    frame["variant"] = frame.kind.where(frame.kind != "", "consistent") + frame.severity.map(lambda s: f" {s:g}")
    print(f"\nretracked by LK from a {stride} px grid: SGC (reward)")
    table = frame.pivot(index="cell", columns="variant", values="sgc").round(3)
    print(table.assign(gt_p95_px=frame.groupby("cell").gt_p95.max().round(2)).to_string())
    print("rewards:\n" + frame.pivot(index="cell", columns="variant", values="reward").round(3).to_string())
    print("statuses:", dict(frame.status.value_counts()))
    print("above the consistent twin: " + ", ".join(f"{kind} {severity:g} {share:.0%}" for (kind, severity), share
                                                    in detection_table(frame.to_dict("records")).items()))


def print_rounding(scenes: int, config, sky: bool) -> None:
    print("\nexact clips (1,000 tracks): the depth error as scored, and frame i−1's warp against frame i's depth "
          "at the nearest pixel / interpolated at the point [%]")
    from sgc_jax import score_batch

    for size in ((144, 192), (72, 96)):
        spec = CorridorSpec(height=size[0], width=size[1], sky=sky)
        clips = [Corridor(CORRIDOR_SEEDS[k], spec, moving=False).clip(False, f"{family(sky)}-{k}")
                 for k in range(scenes)]
        scored = score_batch(clips, config=config).clips
        for clip, result in zip(clips, scored):
            nearest, interpolated = rounding_part(clip)
            print(f"{clip.clip_id} {size[1]}x{size[0]}: depth error {result.components['depth_error']:.3f} (SGC {result.sgc:.3f}); "
                  f"nearest {nearest:.3f}, interpolated {interpolated:.4f}")


def main() -> None:
    from sgc_jax import SGCConfig
    from sgc_jax.research.noise import NOISE_MODELS
    from sgc_jax.research.protocol import rows_scored_or_read

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--tracks", type=int, nargs="+", default=[200, 1000, 4096])
    parser.add_argument("--levels", type=float, nargs="+", default=[0.5, 2.0], help="noise levels [px]")
    parser.add_argument("--models", nargs="+", default=list(NOISE_MODELS), choices=sorted(NOISE_MODELS))
    parser.add_argument("--perturb", type=float, default=0.25, help="the perturbations' severity")
    parser.add_argument("--config", default="{}", help="SGCConfig fields as JSON, e.g. a partition")
    parser.add_argument("--out", type=Path, help="write one row per clip (CSV)")
    parser.add_argument("--rows", type=Path, help="print the tables from this CSV (an earlier --out) instead of scoring")
    parser.add_argument("--ladders", action="store_true", help="also each scene's perturbation ladders")
    parser.add_argument("--street", action="store_true", help="a street: no ceiling, sky above the walls")
    parser.add_argument("--tracked", type=int, default=0, metavar="STRIDE",
                        help="also the clips retracked by LK on their own frames from a grid of STRIDE px")
    args = parser.parse_args()
    args.score_config = SGCConfig(**json.loads(args.config))
    rows = rows_scored_or_read(args.rows, args.out, lambda: score_rows(args),
                               text=("scene", "model", "kind", "status", "cell"), integers=("tracks",))
    print_tables(rows)
    if not args.rows:
        print_rounding(args.scenes, args.score_config, args.street)
    if args.ladders:
        print_ladders(args.scenes, args.score_config, args.street)
    if args.tracked:
        print_tracked(args.scenes, args.score_config, args.street, args.tracked)


if __name__ == "__main__":
    main()

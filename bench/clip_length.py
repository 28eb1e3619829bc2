"""Long clips whose frames move little: what an inconsistency that grows slowly over the clip shows
each pair, and the same clip scored at a frame step (docs/semantics.md §1.5, §7.4).

    python bench/clip_length.py [--scenes 6] [--frames 33] [--step 4] [--speed 0.5] [--tracks 1000]

Scene k of the unseen pool (``research.protocol.random_scene``: seeds 7200-, report-only; its layout
and size, its camera's motion a frame times ``--speed``) is drawn twice:

- *long*: ``--frames`` frames;
- *stepped*: the frames a step of ``--step`` keeps of it, (frames - 1) / step + 1 frames with step
  times the camera's motion a frame and the perturbations' phase drift a frame step times theirs,
  as `sgc-jax import --frame-step` makes a clip from long-range tracks (the camera path's shape
  follows the clip's progress, so it is the long clip's path at every step-th frame to first order;
  the perturbations' ramps over the clip are the same).

Each is scored consistent and with the paper's three perturbations at severity 0.25 (which grow
linearly to the last frame: a longer clip gives each pair a smaller share), under independent
Gaussian errors on both ends of every track at 0.5 and 2 px (``research.noise``, iid-both), the
perturbed clips given their consistent clip's noise draw. Prints per form and level: the consistent
clips above 0.10 and the largest, each perturbation's share of scenes above its consistent twin
and its reward against the twin's (docs/semantics.md §9.4: what a reward on consecutive pairs pays
a slow drift), and the consistent clips' median evidence and reward.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from sgc_jax import score_batch
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.protocol import ProtocolScene, random_scene

SEVERITY = 0.25
LEVELS_PX = (0.5, 2.0)
PHASED = ("warp", "depth_warp")  # perturbations whose sinusoid drifts by a phase a frame


def scene_at(k: int, frames: int, speed: float) -> ProtocolScene:
    """Unseen scene k with ``frames`` frames and its camera's motion a frame times ``speed``."""
    scene = random_scene(k)
    spec = dict(scene.spec, n_frames=frames, rot_deg_per_frame=scene.spec["rot_deg_per_frame"] * speed,
                trans_per_frame=scene.spec["trans_per_frame"] * speed)
    return ProtocolScene(scene.name, scene.seed, spec)


def variants(scene: ProtocolScene, tracks: int, phase_factor: float, form: str) -> tuple[list, list[dict]]:
    exact = scene.clip(tracks)
    clips, rows = [], []
    for px in LEVELS_PX:
        errors = NOISE_MODELS["iid-both"].replace(px=px)
        for kind in ("", *PERTURBATIONS):
            params = {"phase_per_frame": 0.5 * phase_factor} if kind in PHASED else {}
            base = perturb_clip(exact, kind, SEVERITY, **params) if kind else exact
            noisy = add_noise(base, errors, seed=scene.seed * 10 + LEVELS_PX.index(px))
            clips.append(dataclasses.replace(noisy, clip_id=f"{scene.name}-{form}-{px:g}-{kind or 'consistent'}"))
            rows.append(dict(form=form, scene=scene.name, px=px, kind=kind))
    return clips, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=33)
    parser.add_argument("--step", type=int, default=4)
    parser.add_argument("--speed", type=float, default=0.5, help="times each scene's camera motion a frame")
    parser.add_argument("--tracks", type=int, default=1000)
    args = parser.parse_args()
    if (args.frames - 1) % args.step:
        raise SystemExit(f"--frames - 1 ({args.frames - 1}) must be a multiple of --step ({args.step})")
    stepped_frames = (args.frames - 1) // args.step + 1
    forms = {"long": (args.frames, args.speed, 1.0),
             "stepped": (stepped_frames, args.speed * args.step, float(args.step))}
    clips, rows = [], []
    for k in range(args.scenes):
        for form, (frames, speed, phase_factor) in forms.items():
            more_clips, more_rows = variants(scene_at(k, frames, speed), args.tracks, phase_factor, form)
            clips += more_clips
            rows += more_rows
    start = time.perf_counter()
    result = score_batch(clips, progress=False)
    rewards = result.rewards()["reward"]
    print(f"{len(clips)} clips scored in {time.perf_counter() - start:.0f} s (programs compiled or loaded included)")
    for row, scored, reward in zip(rows, result.clips, rewards):
        row.update(sgc=scored.sgc, evidence=scored.evidence, reward=float(reward), status=scored.status)

    print(f"\n{args.scenes} unseen scenes, {args.tracks} tracks a pair, iid-both; long: {args.frames} frames at "
          f"{args.speed:g}x the scene's motion a frame; stepped: {stepped_frames} frames, every {args.step}th")
    print("| form | px | consistent above 0.10 (largest) | "
          + " | ".join(f"{k} at {SEVERITY:g} above its twin (reward, x the twin's: median)" for k in PERTURBATIONS)
          + " | consistent: evidence, reward (medians) |")
    print("|---|---|---|" + "---|" * (len(PERTURBATIONS) + 1))
    for form in forms:
        for px in LEVELS_PX:
            cell = [r for r in rows if r["form"] == form and r["px"] == px]
            twin = {r["scene"]: r for r in cell if not r["kind"]}
            consistent = np.array([r["sgc"] for r in twin.values()])
            shares = []
            for kind in PERTURBATIONS:
                perturbed = [r for r in cell if r["kind"] == kind]
                above = sum(r["sgc"] > twin[r["scene"]]["sgc"] for r in perturbed)
                paid = np.median([r["reward"] / max(twin[r["scene"]]["reward"], 1e-9) for r in perturbed])
                shares.append(f"{above} of {len(perturbed)} ({paid:.2f}x)")
            evidence = np.median([r["evidence"] for r in twin.values()])
            reward = np.median([r["reward"] for r in twin.values()])
            print(f"| {form} | {px:g} | {int((consistent > 0.10).sum())} of {len(consistent)} ({consistent.max():.3f}) | "
                  + " | ".join(shares) + f" | {evidence:.2f}, {reward:.3f} |")


if __name__ == "__main__":
    main()

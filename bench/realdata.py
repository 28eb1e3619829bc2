"""Real footage of a rigid world (issue 41): the clips of ``../shared/realdata/`` (static scenes with
ground-truth depth and cameras and real tracks; its README says how they were made) under the
default config and calibration: SGC, its interval, and each pose component against its noise floor
(the bars: SGC <= 0.05, each component within 2x its floor).

    python bench/realdata.py [--dir ../shared/realdata] [--engine jax] [--out realdata.csv]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sgc_jax import COMPONENTS, score_batch

POSE_COMPONENTS = [c for c in COMPONENTS if c != "depth_error"]
DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "realdata"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default=str(DEFAULT_DIR))
    parser.add_argument("--engine", default="jax")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    paths = sorted(Path(args.dir).glob("*.npz"))
    if not paths:
        raise SystemExit(f"no .npz clips in {args.dir}")
    result = score_batch([str(p) for p in paths], engine=args.engine, progress=False)
    print("| clip | SGC | 90 % interval | " + " | ".join(f"{k} / floor" for k in POSE_COMPONENTS)
          + " | depth_error % | tracks per pair |")
    print("|---|---|---|" + "---|" * (len(POSE_COMPONENTS) + 2))
    for path, clip in zip(paths, result.clips):
        ratios = [clip.components[k] / clip.floors[f"{k}_floor"] for k in POSE_COMPONENTS]
        tracks = int(clip.pairs.n_tracks.mean()) if clip.pairs is not None else 0
        print(f"| {path.stem} | {clip.sgc:.3f} | {clip.sgc_lo:.3f}-{clip.sgc_hi:.3f} | "
              + " | ".join(f"{r:.2f}" for r in ratios) + f" | {clip.components['depth_error']:.2f} | {tracks} |")
    if args.out:
        result.to_pandas().to_csv(args.out, index=False)


if __name__ == "__main__":
    main()

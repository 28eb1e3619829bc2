"""The ``sgc-jax`` command line: score, demo, synth."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Sequence

from .calibration import COMPONENTS


def _add_algorithm_flags(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("algorithm")
    group.add_argument("--engine", choices=("jax", "reference"), default="jax",
                       help="jax: jitted kernels (default); reference: NumPy + OpenCV oracle")
    group.add_argument("--calibration", default="sgc-paper-2026",
                       help="shipped calibration name or a calibration JSON file (default: sgc-paper-2026)")
    group.add_argument("--partition", choices=("depth", "grid", "depth+spatial"), default="depth")
    group.add_argument("--no-mos", action="store_true", help="ignore the static masks (paper's no-MOS ablation)")
    group.add_argument("--align-scale", action="store_true",
                       help="fit one scale per clip between local (depth) and global (pose) translations")
    group.add_argument("--compat", choices=("spec", "authors"), default="spec",
                       help="authors: reproduce the paper code's choices (SPEC §3a)")
    group.add_argument("--seed", type=int, default=0, help="RANSAC seed")


def _config_overrides(args: argparse.Namespace) -> dict:
    return dict(partition=args.partition, use_mos=not args.no_mos, align_scale=args.align_scale,
                compat=args.compat, seed=args.seed)


def _summary_line(result) -> str:
    counts = {s: sum(1 for c in result.clips if c.status == s) for s in ("ok", "partial", "error")}
    return f"{len(result)} clip(s): {counts['ok']} ok, {counts['partial']} partial, {counts['error']} error"


def cmd_score(args: argparse.Namespace) -> int:
    from .api import score_batch

    try:
        result = score_batch(list(args.paths), calibration=args.calibration, engine=args.engine,
                             progress=not args.quiet, **_config_overrides(args))
    except (FileNotFoundError, ValueError) as exc:
        print(f"sgc-jax score: {exc}", file=sys.stderr)
        return 2
    for clip in result.clips:
        if clip.status == "error":
            print(f"sgc-jax score: {clip.clip_id} ({clip.origin}): {clip.reason}", file=sys.stderr)
    if args.out:
        result.to_csv(args.out, pairs_path=args.pairs)
        print(f"wrote {args.out}" + (f" and {args.pairs}" if args.pairs else ""), file=sys.stderr)
    elif args.pairs:
        result.to_csv(Path(args.pairs).with_name("scores.csv"), pairs_path=args.pairs)
    if not args.out or not args.quiet:
        print(result.table())
    print(_summary_line(result), file=sys.stderr)
    return 0 if any(c.status != "error" for c in result.clips) else 1


def cmd_synth(args: argparse.Namespace) -> int:
    from .synth import write_demo_corpus

    paths = write_demo_corpus(args.out, seed=args.seed)
    for p in paths:
        print(p)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .api import score_batch
    from .synth import write_demo_corpus

    with tempfile.TemporaryDirectory() as tmp:
        out_dir = Path(args.out) if args.out else Path(tmp)
        paths = write_demo_corpus(out_dir, seed=args.seed)
        print(f"synthesised {len(paths)} demo clips in {out_dir}", file=sys.stderr)
        result = score_batch(out_dir, engine=args.engine, progress=not args.quiet)
    print(result.table(("clip_id", "group", "status", "sgc", *COMPONENTS, "n_pairs_scored")))
    print(_summary_line(result), file=sys.stderr)
    print("lower SGC = more consistent; rigid clips should score lowest", file=sys.stderr)
    return 0 if all(c.status != "error" for c in result.clips) else 1


def _register_score(sub) -> None:
    score = sub.add_parser("score", help="score clip / batch .npz files, directories or globs")
    score.add_argument("paths", nargs="+", help="clip or batch .npz files, directories, globs")
    output = score.add_argument_group("output")
    output.add_argument("--out", help="per-clip CSV (columns as in SPEC §6)")
    output.add_argument("--pairs", help="per-pair CSV")
    _add_algorithm_flags(score)
    score.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no table when --out")
    score.set_defaults(func=cmd_score)


def _register_demo(sub) -> None:
    demo = sub.add_parser("demo", help="synthesise a small corpus, score it and print the table")
    demo.add_argument("--out", help="keep the demo clips in this directory")
    demo.add_argument("--engine", choices=("jax", "reference"), default="jax")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("-q", "--quiet", action="store_true")
    demo.set_defaults(func=cmd_demo)


def _register_synth(sub) -> None:
    synth = sub.add_parser("synth", help="write the synthetic demo corpus as clip .npz files")
    synth.add_argument("--out", required=True, help="output directory")
    synth.add_argument("--seed", type=int, default=0)
    synth.set_defaults(func=cmd_synth)


# One registrar per subcommand, in the order ``sgc-jax --help`` lists them.
SUBCOMMANDS = (
    _register_score,
    _register_demo,
    _register_synth,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sgc-jax", description="Spatial Geometric Consistency scores")
    sub = parser.add_subparsers(dest="command", required=True)
    for register in SUBCOMMANDS:
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

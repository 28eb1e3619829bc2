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


def _read_scores_or_exit(paths, command: str):
    from .result import read_scores

    try:
        return read_scores(paths)
    except (OSError, ValueError) as exc:
        print(f"sgc-jax {command}: {exc}", file=sys.stderr)
        return None


def cmd_calibrate(args: argparse.Namespace) -> int:
    import dataclasses

    from .calibration import calibrate, kfold_stability
    from .result import rescore_records, write_scores

    records = _read_scores_or_exit(args.scores, "calibrate")
    if records is None:
        return 2
    try:
        calibration = calibrate(records, by=args.by, name=args.name)
    except ValueError as exc:
        print(f"sgc-jax calibrate: {exc}", file=sys.stderr)
        return 2
    print(f"calibration {calibration.name!r}: {calibration.description}")
    print(f"{'component':<18}{'log1p':>6}{'mu':>10}{'sigma':>10}{'z_min':>9}{'z_max':>9}{'weight':>9}")
    for k in COMPONENTS:
        print(f"{k:<18}{'yes' if calibration.log1p[k] else 'no':>6}{calibration.mu[k]:>10.4f}"
              f"{calibration.sigma[k]:>10.4f}{calibration.z_min[k]:>9.4f}{calibration.z_max[k]:>9.4f}"
              f"{calibration.weight[k]:>9.4f}")
    print(f"PC1 explained variance ratio: {calibration.extra['pc1_explained_variance_ratio']:.4f}")
    if args.folds:
        try:
            stability = kfold_stability(records, k=args.folds, by=args.by, seed=args.seed)
        except ValueError as exc:
            print(f"k-fold stability not computed: {exc}", file=sys.stderr)
        else:
            print(f"\n{args.folds}-fold stability of the weights:")
            print(stability.table())
            calibration = dataclasses.replace(
                calibration, extra={**calibration.extra, "kfold_stability": stability.to_dict()})
    if args.out:
        calibration.save(args.out)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.rescored:
        write_scores(args.rescored, rescore_records(records, calibration))
        print(f"wrote {args.rescored} (sgc under the new calibration, from the stored components)", file=sys.stderr)
    return 0


def cmd_rescore(args: argparse.Namespace) -> int:
    from .result import format_table, rescore_records, write_scores

    records = _read_scores_or_exit(args.scores, "rescore")
    if records is None:
        return 2
    try:
        rescored = rescore_records(records, args.calibration)
    except (FileNotFoundError, ValueError) as exc:
        print(f"sgc-jax rescore: {exc}", file=sys.stderr)
        return 2
    if args.out:
        write_scores(args.out, rescored)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        print(format_table(rescored, ("clip_id", "group", "status", "sgc", *COMPONENTS, "ecd")))
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from .compare import (CLIP_TABLE_COLUMNS, GROUP_COLUMNS, agreement_between, clip_table, group_table,
                          motion_dependence)
    from .result import write_csv, format_table

    records = _read_scores_or_exit(args.scores, "compare")
    if records is None:
        return 2
    try:
        if args.by == "group":
            table, columns = group_table(records, args.column, n_boot=args.boot, seed=args.seed), GROUP_COLUMNS
        else:
            table, columns = clip_table(records, args.column), CLIP_TABLE_COLUMNS
        motion = motion_dependence(records, args.column)
    except KeyError as exc:
        print(f"sgc-jax compare: {exc.args[0]}", file=sys.stderr)
        return 2
    print(format_table(table, columns))
    if motion["n_ecd"]:
        print(f"\n{args.column} vs ECD over {motion['n_ecd']} clips: Pearson r = {motion['pearson']:.3f} "
              f"(r^2 = {motion['r2']:.3f}), Spearman rho = {motion['spearman']:.3f}")
    if args.out:
        write_csv(args.out, table, columns)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.against:
        other = _read_scores_or_exit(args.against, "compare")
        if other is None:
            return 2
        try:
            agree = agreement_between(records, other, args.column, by=args.by)
        except (KeyError, ValueError) as exc:
            print(f"sgc-jax compare: {exc.args[0]}", file=sys.stderr)
            return 2
        print(f"agreement by {args.by} with {' '.join(args.against)} over {agree['n']} matched "
              f"{'groups' if args.by == 'group' else 'clips'}: Spearman rho = {agree['spearman']:.4f}, "
              f"Kendall tau-b = {agree['kendall_tau']:.4f}, Pearson r = {agree['pearson']:.4f}")
        if agree["unmatched"]:
            print(f"{len(agree['unmatched'])} unmatched: {', '.join(agree['unmatched'][:10])}"
                  + (" ..." if len(agree["unmatched"]) > 10 else ""), file=sys.stderr)
    return 0


def _register_calibrate(sub) -> None:
    cal = sub.add_parser("calibrate", help="fit a calibration (mu, sigma, z bounds, PC1 weights) on scores CSVs")
    cal.add_argument("scores", nargs="+", help="per-clip CSVs from `sgc-jax score --out`")
    algorithm = cal.add_argument_group("algorithm")
    algorithm.add_argument("--by", choices=("clip", "group"), default="clip",
                           help="fit on clips, or on per-group means (the paper's way)")
    algorithm.add_argument("--folds", type=int, default=5, help="k of the k-fold weight stability (0: skip)")
    algorithm.add_argument("--seed", type=int, default=0, help="fold shuffling seed")
    output = cal.add_argument_group("output")
    output.add_argument("--out", help="calibration JSON to write (use with `score --calibration`)")
    output.add_argument("--name", default="custom", help="name stored in the calibration")
    output.add_argument("--rescored", help="also write the input rows re-scored with the new calibration")
    cal.set_defaults(func=cmd_calibrate)


def _register_rescore(sub) -> None:
    res = sub.add_parser("rescore", help="recompute sgc of scores CSVs under another calibration (no geometry)")
    res.add_argument("scores", nargs="+", help="per-clip CSVs from `sgc-jax score --out`")
    res.add_argument("--calibration", required=True, help="shipped calibration name or a calibration JSON file")
    res.add_argument("--out", help="re-scored CSV (default: print the table)")
    res.set_defaults(func=cmd_rescore)


def _register_compare(sub) -> None:
    cmp_ = sub.add_parser("compare", help="per-group / per-clip tables, ECD dependence, agreement of two files")
    cmp_.add_argument("scores", nargs="+", help="per-clip CSVs (read together as one corpus)")
    cmp_.add_argument("--by", choices=("group", "clip"), default="group")
    cmp_.add_argument("--column", default="sgc", help="score column to summarise (default: sgc)")
    cmp_.add_argument("--against", nargs="+", help="other per-clip CSVs: rank agreement per clip or group mean")
    cmp_.add_argument("--boot", type=int, default=2000, help="bootstrap resamples for the 95%% CI")
    cmp_.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    cmp_.add_argument("--out", help="write the table as CSV")
    cmp_.set_defaults(func=cmd_compare)


# One registrar per subcommand, in the order ``sgc-jax --help`` lists them.
SUBCOMMANDS = (
    _register_score,
    _register_demo,
    _register_synth,
    _register_calibrate,
    _register_rescore,
    _register_compare,
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

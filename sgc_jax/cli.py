"""The ``sgc-jax`` command line; exit codes and the input/output guards: docs/semantics.md §8."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import textwrap
import tomllib
import traceback
import typing
import warnings
from pathlib import Path
from typing import Any, Iterable, Sequence

from .adapters.common import DEPTH_RESIZES
from .adapters.delta import DELTA_VIS_THRESHOLD
from .adapters.line_tracks import LINE_RATIO
from .adapters.vggt import MODES as VGGT_MODES
from .calibration import COMPONENTS
from .codes import CLIP_STATUSES
from .config import SGCConfig, cli_flag, renamed_fields
from .io.checks.problems import clip_warnings_as_lines
from .io.depth_edges import DEPTH_EDGE_RATIO
from .io.extras import MissingExtraError
from .scoring.engine_steps import ENGINES
from .scoring.options import READ_IN
from .version import __version__

CLIP_INPUTS_HELP = "clip or batch .npz files, directories, globs or URLs (docs/semantics.md §1, §4.2)"

EXIT_OK = 0  # every input processed
EXIT_SOME_FAILED = 1  # the command ran to the end and wrote its outputs; some inputs were reported as errors
EXIT_USAGE = 2  # nothing done: bad arguments, inputs or outputs (one line on stderr says which)
EXIT_INTERNAL = 3  # a bug in sgc_jax: the traceback is printed
EXIT_INTERRUPTED = 130

EXIT_CODES_HELP = ("exit codes: 0 every input processed; 1 finished, but some inputs were reported as errors "
                   "(outputs written for the rest); 2 nothing done (bad arguments, an input of the wrong kind, "
                   "--out naming an input); 3 internal error (a bug; please report the traceback); 130 "
                   "interrupted (Ctrl-C: rows already written stay, `score --resume` goes on from them). "
                   "docs/semantics.md §8")

# Each subcommand's --help ends with these examples, then the exit codes.
EXAMPLES = {
    "score": ["sgc-jax score clips/ --out scores.csv --pairs pairs.csv",
              "sgc-jax score clips/ --out scores.csv --resume     # after an interruption"],
    "demo": ["sgc-jax demo --out demo_clips/     # keeps the clips, e.g. for the README's Scorer snippet"],
    "synth": ["sgc-jax synth --out demo_clips/ && sgc-jax score demo_clips/"],
    "calibrate": ["sgc-jax calibrate scores.csv --floor-band 1.25 --out calib.json",
                  "sgc-jax score clips/ --calibration calib.json --out scores.csv"],
    "rescore": ["sgc-jax rescore scores.csv --calibration calib.json --out rescored.csv"],
    "compare": ["sgc-jax compare scores.csv --by group --plot groups.png",
                "sgc-jax compare spec.csv --against authors.csv --by clip"],
    "import": ["sgc-jax import --cameras vggt/predictions.npz --depth vda/clip_depths.npz --depth-kind disparity \\",
               "               --tracks delta/ --masks seganymo/clip/ --frames frames/ --out clips/clip.npz",
               "sgc-jax import --da3 da3/exports/npz/results.npz --tracks cotracker.npz --frames frames/ "
               "--out clips/clip.npz",
               "sgc-jax validate clips/ && sgc-jax score clips/ --out scores.csv"],
    "pack": ["sgc-jax pack clips/ --out batch.npz && sgc-jax score batch.npz --out scores.csv"],
    "validate": ["sgc-jax validate clips/ --strict -v"],
    "perturb": ["sgc-jax perturb clips/ --kinds warp,squeeze,depth_warp --severities 0,0.25,0.5 --summary study.csv"],
}


class UsageError(Exception):
    """A command line that cannot run as given: one line on stderr, exit 2, nothing read or written."""


# ----------------------------------------------------------------------------- input and output guards
_NOT_A_CLIP_HINTS = {
    ".csv": "a scores table; `sgc-jax rescore`, `compare` and `calibrate` read those",
    ".npy": "a single array; a clip is an .npz archive of named arrays (docs/semantics.md §1.2)",
    ".json": "a calibration file (--calibration) or a configuration file (--config)?",
}


def _file_key(path: str | os.PathLike) -> tuple | str:
    """One key per file on disk: (device, inode) of an existing file (hard and symbolic links
    included), else its resolved path."""
    try:
        st = os.stat(path)
        return (st.st_dev, st.st_ino)
    except OSError:
        return os.path.realpath(path)


def clip_input_files(paths: Iterable[str]) -> list[Path]:
    """The files that clip arguments name; a named file that is not an ``.npz`` is refused with a
    hint (directories and globs contribute their ``.npz`` files only)."""
    from .io.loading import list_clip_files

    files: list[Path] = []
    for text in paths:
        suffix = Path(text).suffix.lower()
        if os.path.lexists(text) and not os.path.isdir(text) and suffix != ".npz":
            hint = _NOT_A_CLIP_HINTS.get(suffix, "clip and batch files are .npz archives (docs/semantics.md §1)")
            raise UsageError(f"{text}: not a clip file (.npz): {hint}")
        try:
            files += list_clip_files(text, allow_empty=True)
        except FileNotFoundError as exc:
            raise UsageError(str(exc)) from None
    return files


def table_input_files(paths: Iterable[str]) -> list[Path]:
    """Scores CSVs named on the command line; a clip file is refused with a hint."""
    for text in paths:
        if Path(text).suffix.lower() == ".npz":
            raise UsageError(f"{text}: a clip file; this command reads the scores CSV that "
                             f"`sgc-jax score --out` writes (score the clips first)")
        if not os.path.isfile(text):
            raise UsageError(f"{text}: no such file")
    return [Path(t) for t in paths]


def guard_outputs(inputs: Iterable[str | os.PathLike | None], **outputs: str | os.PathLike | None) -> None:
    """Refuse an output that is an input, a directory, or the same file as another output
    (``outputs``: flag name -> path; None, as an input or an output, when not given)."""
    taken = {_file_key(p): None for p in inputs if p is not None}
    for flag, path in outputs.items():
        if path is None:
            continue
        option = "--" + flag.replace("_", "-")
        if os.path.isdir(path):
            raise UsageError(f"{option} {path}: a directory; give a file name")
        key = _file_key(path)
        if key in taken:
            other = taken[key]
            raise UsageError(f"{option} {path} " + (f"is the same file as {other}" if other else
                             "is one of the inputs and would be overwritten; choose another file name"))
        taken[key] = option


def _calibration_file(calibration: str | None) -> str | None:
    """``--calibration`` when it names a file (an input the outputs must not overwrite), else None."""
    return calibration if calibration is not None and os.path.isfile(calibration) else None


def _config_option_kwargs(field: dataclasses.Field, kind: Any) -> dict[str, Any]:
    """``add_argument`` keywords of one SGCConfig field: its help and default from config.py, no
    parsed default (so a flag left out does not override ``--config``)."""
    default = field.default
    if isinstance(default, bool):
        default = "on" if default else "off"
    shown = "" if default is None else f" (default: {default})"
    kwargs = dict(dest=field.name, default=argparse.SUPPRESS, help=field.metadata["help"].replace("%", "%%") + shown)
    if kind is bool or bool in typing.get_args(kind):
        return {**kwargs, "action": argparse.BooleanOptionalAction}
    if field.metadata.get("choices"):
        return {**kwargs, "choices": field.metadata["choices"]}
    if kind in (int, float):
        return {**kwargs, "type": kind, "metavar": kind.__name__.upper()}
    raise TypeError(f"SGCConfig.{field.name}: no command-line form for a field of type {kind}")


def _add_algorithm_flags(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("algorithm")
    group.add_argument("--engine", choices=ENGINES, default="jax",
                       help="jax: jitted kernels (default); reference: NumPy + OpenCV oracle")
    group.add_argument("--calibration", default=None,
                       help="shipped calibration name or a calibration JSON file (default: sgc-spec-2026, or "
                            "sgc-paper-2026 with --compat authors; docs/semantics.md §5)")
    group.add_argument("--config", metavar="FILE",
                       help="SGCConfig fields as a JSON object, or TOML when FILE ends in .toml (e.g. "
                            '{"inlier_px": 6, "partition": "grid"}); the options below override it')
    fields = parser.add_argument_group("configuration",
                                       "SGCConfig fields (docs/semantics.md §2); each overrides --config")
    hints = typing.get_type_hints(SGCConfig)
    for field in dataclasses.fields(SGCConfig):
        fields.add_argument(cli_flag(field), **_config_option_kwargs(field, hints[field.name]))


def _use_compilation_cache(engine: str) -> None:
    """The JAX engine's compiled programs persist between runs (``compile_cache``; off with
    ``SGC_JAX_COMPILATION_CACHE=off``)."""
    if engine == "jax":
        from .engines.jax_engine.compile_cache import enable_compilation_cache

        enable_compilation_cache()


def _progress(args: argparse.Namespace) -> bool | None:
    """A progress bar on a terminal unless ``-q``; piped (a log), none: its carriage returns would
    cut the compile notices' lines (docs/semantics.md §7.1)."""
    return False if args.quiet else None


def _read_config_file(path: str) -> dict[str, Any]:
    """``--config FILE``: a JSON object (TOML when the name ends in ``.toml``) of SGCConfig fields,
    each value of its field's type."""
    try:
        text = Path(path).read_bytes().decode()
        values = tomllib.loads(text) if path.lower().endswith(".toml") else json.loads(text)
    except OSError as exc:
        raise UsageError(f"--config {path}: {exc.strerror or exc}") from None
    except ValueError as exc:  # JSONDecodeError, TOMLDecodeError, UnicodeDecodeError
        raise UsageError(f"--config {path}: not a {'TOML' if path.lower().endswith('.toml') else 'JSON'} "
                         f"file: {exc}") from None
    if not isinstance(values, dict):
        raise UsageError(f"--config {path}: expected an object of SGCConfig fields, got {type(values).__name__}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DeprecationWarning)
        try:
            values = renamed_fields(values)
        except TypeError as exc:
            raise UsageError(f"--config {path}: {exc}") from None
    for warning in caught:
        print(f"sgc-jax: --config {path}: {warning.message}", file=sys.stderr)
    hints = typing.get_type_hints(SGCConfig)
    for field in dataclasses.fields(SGCConfig):
        if field.name not in values:
            continue
        value, kind = values[field.name], hints[field.name]
        types = typing.get_args(kind) or (kind,)  # bool | None -> (bool, NoneType)
        if float in types:
            types += (int,)  # 6 for 6.0
        if type(value) not in types:  # exact: true is not an int
            raise UsageError(f"--config {path}: {field.name} must be {getattr(kind, '__name__', kind)}, "
                             f"got {value!r}")
        if kind is float:
            values[field.name] = float(value)
    return values


def _config_and_calibration(args: argparse.Namespace):
    """The SGCConfig and Calibration of the algorithm flags over ``--config``, resolved before any
    clip is read (so that only a bad flag, never an engine's exception, becomes a usage error)."""
    from .scoring.api import resolve_calibration

    values = _read_config_file(args.config) if args.config else {}
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(SGCConfig) if hasattr(args, f.name)}
    try:
        config = SGCConfig.from_dict({**values, **given})
    except TypeError as exc:  # an unknown field in the file
        raise UsageError(f"--config {args.config}: {exc}") from None
    except ValueError as exc:  # a value out of its range
        raise UsageError(str(exc)) from None
    try:
        return config, resolve_calibration(args.calibration, config)
    except (OSError, ValueError) as exc:  # an unknown calibration name or file, one for the other compat
        raise UsageError(str(exc)) from None


def _summary_line(result) -> str:
    counts = {s: sum(1 for c in result.clips if c.status == s) for s in CLIP_STATUSES}
    warned = sum(1 for c in result.clips if c.warnings)
    return (f"{len(result)} clip(s): " + ", ".join(f"{n} {s}" for s, n in counts.items())
            + (f"; {warned} with content warnings (column warnings, docs/semantics.md §1.6)" if warned else ""))


def _connect_ray(address: str) -> None:
    """``--ray``: join (or start) the cluster now, so that a missing extra or cluster is a usage error."""
    from .scoring.cluster import connect

    try:
        connect(address)
    except ImportError as exc:
        raise UsageError(str(exc)) from None
    except ConnectionError as exc:
        raise UsageError(f"--ray {address}: {exc} (start one with `ray start --head`, or use --ray local)") from None


def cmd_score(args: argparse.Namespace) -> int:
    from .scoring.api import score_batch
    from .scoring.streaming import StreamStats

    out = args.out or (Path(args.pairs).with_name("scores.csv") if args.pairs else None)
    inputs = clip_input_files(args.paths)
    if not inputs:
        raise UsageError(f"no .npz clips in {' '.join(args.paths)}")
    guard_outputs([*inputs, args.config, _calibration_file(args.calibration)], out=out, pairs=args.pairs)
    if args.devices < 0:
        raise UsageError(f"--devices must be 0 (all) or more, got {args.devices}")
    if args.lanes < 0:
        raise UsageError(f"--lanes must be 0 (the default) or more, got {args.lanes}")
    if args.readers < 0:
        raise UsageError(f"--readers must be 0 (the default) or more, got {args.readers}")
    if args.resume and not out:
        raise UsageError("--resume needs --out: the output of the run to resume")
    if args.ray_scorers < 0 or (args.ray_scorers and args.ray is None):
        raise UsageError(f"--ray-scorers must be 1 or more and goes with --ray, got {args.ray_scorers}")
    config, calibration = _config_and_calibration(args)
    _use_compilation_cache(args.engine)
    stats = StreamStats()
    if args.ray is not None:
        _connect_ray(args.ray)
        if not args.quiet:
            print(f"sgc-jax score: scoring on the Ray cluster at {args.ray}"
                  + (f" with {args.ray_scorers} scorer(s)" if args.ray_scorers else ""), file=sys.stderr)
    result = score_batch(list(args.paths), config=config, calibration=calibration, engine=args.engine,
                         progress=_progress(args), out=out, pairs_out=args.pairs, resume=args.resume,
                         devices=args.devices or None, lanes=args.lanes or None, readers=args.readers or None,
                         read_in=args.read_in, ray_address=args.ray, ray_scorers=args.ray_scorers or None,
                         stats=stats)
    for clip in result.clips:
        if clip.status == "error":
            print(f"sgc-jax score: {clip.clip_id} ({clip.origin}): {clip.reason}", file=sys.stderr)
        elif clip.status == "low_evidence":  # scored, on too little to see an inconsistency (§3.11)
            print(f"sgc-jax score: {clip.clip_id}: low evidence, {clip.reason}", file=sys.stderr)
    if args.resume:
        print(f"resumed: {stats.resumed} clip(s) kept from {out}, {stats.scored + stats.errors} read and scored",
              file=sys.stderr)
    if out:
        print(f"wrote {out}" + (f" and {args.pairs}" if args.pairs else ""), file=sys.stderr)
    if not args.out or not args.quiet:
        print(result.table())
    print(_summary_line(result), file=sys.stderr)
    return EXIT_SOME_FAILED if any(c.status == "error" for c in result.clips) else EXIT_OK


def cmd_synth(args: argparse.Namespace) -> int:
    from .research.synth import write_demo_corpus

    paths = write_demo_corpus(args.out, seed=args.seed)
    for p in paths:
        print(p)
    return EXIT_OK


def cmd_demo(args: argparse.Namespace) -> int:
    from .io.tables import INTERVAL_COLUMNS
    from .research.synth import demo_claims, write_demo_corpus
    from .scoring.api import score_batch

    _use_compilation_cache(args.engine)
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = Path(args.out) if args.out else Path(tmp)
        paths = write_demo_corpus(out_dir, seed=args.seed)
        where = f"in {out_dir}" if args.out else "for this run only (--out DIR keeps them)"
        print(f"synthesised {len(paths)} demo clips {where}", file=sys.stderr)
        result = score_batch(out_dir, engine=args.engine, progress=_progress(args))
    print(result.table(("clip_id", "group", "status", "sgc", *INTERVAL_COLUMNS, *COMPONENTS, "n_pairs_scored",
                        "evidence")))
    print(_summary_line(result), file=sys.stderr)
    print("lower SGC = more consistent (units and calibration: docs/semantics.md §4-5); in this corpus:",
          file=sys.stderr)
    for claim, holds in demo_claims({c.clip_id: c.sgc for c in result.clips}):
        print(f"  {'yes' if holds else 'NOT SO in this run'}: {claim}", file=sys.stderr)
    return EXIT_SOME_FAILED if any(c.status == "error" for c in result.clips) else EXIT_OK


def _register_score(sub) -> None:
    score = sub.add_parser("score", help="score clip / batch .npz files, directories, globs or URLs",
                           description="Score every clip: SGC, its interval and components per clip "
                                       "(docs/semantics.md §3-§5).")
    score.add_argument("paths", nargs="+", help=CLIP_INPUTS_HELP)
    output = score.add_argument_group("output")
    output.add_argument("--out", help="per-clip table, CSV or .parquet (columns: docs/semantics.md §4)")
    output.add_argument("--pairs", help="per-pair table, CSV or .parquet (docs/semantics.md §4); without --out, the "
                        "per-clip table goes to scores.csv beside it")
    score.add_argument("--devices", type=int, default=0, metavar="N",
                       help="JAX engine: spread the clips over the first N local devices (default 0: all of them)")
    score.add_argument("--lanes", type=int, default=0, metavar="N",
                       help="clips scored at once on the devices (default 0: one per core up to two on a CPU, two "
                            "on an accelerator; docs/semantics.md §4.1); the numbers do not depend on it")
    score.add_argument("--readers", type=int, default=0, metavar="N",
                       help="clip readers (default 0: two threads; on a host of more than 4 cores one process per "
                            "core but two)")
    score.add_argument("--read-in", choices=READ_IN, default="auto",
                       help="read the clip files in threads or processes (default auto: processes on a host of more "
                            "than 4 cores; docs/semantics.md §4.1)")
    score.add_argument("--ray", metavar="ADDRESS",
                       help="score on a Ray cluster: 'auto' (the one this machine belongs to), 'local' (start one "
                            "here) or its address; inputs must be readable from every node: a shared folder or a "
                            "URL such as s3://bucket/clips/ (docs/semantics.md §4.2; pip install 'sgc-jax[ray]')")
    score.add_argument("--ray-scorers", type=int, default=0, metavar="N",
                       help="with --ray: N scorer processes (default 0: one per GPU of the cluster, else per node)")
    output.add_argument("--resume", action="store_true",
                        help="keep the clips --out already holds for the same file content, version, engine, "
                             "configuration and calibration; score the rest (docs/semantics.md §4.1)")
    _add_algorithm_flags(score)
    score.add_argument("-q", "--quiet", action="store_true", help="no progress bar (shown on a terminal), no table when --out")
    score.set_defaults(func=cmd_score)


def _register_demo(sub) -> None:
    demo = sub.add_parser("demo", help="synthesise a small corpus, score it and print the table",
                          description="Synthesise the demo corpus (rigid, noisy, moving-object, unmasked and "
                                      "non-rigid clips), score it, print the table and check the claims it "
                                      "demonstrates (docs/semantics.md §4, §5).")
    demo.add_argument("--out", help="keep the demo clips in this directory")
    demo.add_argument("--engine", choices=ENGINES, default="jax",
                      help="jax: jitted kernels (default); reference: NumPy + OpenCV oracle")
    demo.add_argument("--seed", type=int, default=0, help="seed of the synthetic corpus (default 0)")
    demo.add_argument("-q", "--quiet", action="store_true", help="no progress bar (shown on a terminal)")
    demo.set_defaults(func=cmd_demo)


def _register_synth(sub) -> None:
    synth = sub.add_parser("synth", help="write the synthetic demo corpus as clip .npz files",
                           description="Write the demo corpus as clip files (docs/semantics.md §1.2), to score "
                                       "or inspect.")
    synth.add_argument("--out", required=True, help="(required) output directory")
    synth.add_argument("--seed", type=int, default=0, help="seed of the synthetic corpus (default 0)")
    synth.set_defaults(func=cmd_synth)


def _read_scores(paths) -> list[dict]:
    """Rows of the scores CSVs named on the command line (UsageError for anything else)."""
    from .io.tables import read_scores

    records = []
    for path in table_input_files(paths):
        try:
            records += read_scores(path)
        except UnicodeDecodeError:
            raise UsageError(f"{path}: not a scores CSV (not text)") from None
        except (OSError, ValueError) as exc:
            raise UsageError(str(exc)) from None
    return records


def cmd_calibrate(args: argparse.Namespace) -> int:
    import warnings

    from .calibration import calibrate, kfold_stability
    from .io.tables import write_scores
    from .scoring.result import rescore_records

    guard_outputs(table_input_files(args.scores), out=args.out, rescored=args.rescored)
    records = _read_scores(args.scores)
    try:
        calibration = calibrate(records, by=args.by, name=args.name, floor_band=args.floor_band)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    print(f"calibration {calibration.name!r}: {calibration.description}")
    print(f"{'component':<18}{'log1p':>6}{'mu':>10}{'sigma':>10}{'z_min':>9}{'z_max':>9}{'weight':>9}")
    for k in COMPONENTS:
        print(f"{k:<18}{'yes' if calibration.log1p[k] else 'no':>6}{calibration.mu[k]:>10.4f}"
              f"{calibration.sigma[k]:>10.4f}{calibration.z_min[k]:>9.4f}{calibration.z_max[k]:>9.4f}"
              f"{calibration.weight[k]:>9.4f}")
    print(f"PC1 explained variance ratio: {calibration.extra['pc1_explained_variance_ratio']:.4f}")
    if args.folds:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                stability = kfold_stability(records, k=args.folds, by=args.by, seed=args.seed,
                                            floor_band=args.floor_band)
        except ValueError as exc:
            print(f"k-fold stability not computed: {exc}", file=sys.stderr)
        else:
            for warning in caught:
                print(f"sgc-jax calibrate: warning: {warning.message}", file=sys.stderr)
            print(f"\n{stability.k}-fold stability of the weights:")
            print(stability.table())
            calibration = dataclasses.replace(
                calibration, extra={**calibration.extra, "kfold_stability": stability.to_dict()})
    if args.out:
        calibration.save(args.out)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.rescored:
        write_scores(args.rescored, rescore_records(records, calibration))
        print(f"wrote {args.rescored} (sgc under the new calibration, from the stored components)", file=sys.stderr)
    return EXIT_OK


def cmd_rescore(args: argparse.Namespace) -> int:
    from .io.tables import format_table, write_scores
    from .scoring.result import rescore_records

    guard_outputs([*table_input_files(args.scores), _calibration_file(args.calibration)], out=args.out)
    records = _read_scores(args.scores)
    try:
        rescored = rescore_records(records, args.calibration)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if args.out:
        write_scores(args.out, rescored)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        print(format_table(rescored, ("clip_id", "group", "status", "sgc", *COMPONENTS, "ecd")))
    return EXIT_OK


def _require_matplotlib() -> None:
    """Fail before any work when ``--plot`` cannot be honoured."""
    try:
        from .research.plot import import_pyplot
        import_pyplot()
    except ImportError as exc:
        raise UsageError(f"--plot: {exc}") from None


def cmd_compare(args: argparse.Namespace) -> int:
    from .io.tables import format_table, write_csv
    from .research.compare import (
        CLIP_TABLE_COLUMNS,
        GROUP_COLUMNS,
        MIN_N,
        agreement_between,
        clip_table,
        format_group_table,
        format_ranking,
        group_table,
        motion_dependence,
        ranking_table,
    )

    if args.plot:
        _require_matplotlib()
    guard_outputs(table_input_files([*args.scores, *(args.against or [])]), out=args.out, plot=args.plot)
    records = _read_scores(args.scores)
    try:
        if args.by == "group":
            table, columns = group_table(records, args.column, n_boot=args.boot, seed=args.seed), GROUP_COLUMNS
        else:
            table, columns = clip_table(records, args.column), CLIP_TABLE_COLUMNS
        motion = motion_dependence(records, args.column)
    except KeyError as exc:
        raise UsageError(exc.args[0]) from None
    print(format_group_table(table) if args.by == "group" else format_table(table, columns))
    if motion["n_ecd"] >= MIN_N:
        print(f"\n{args.column} vs ECD over {motion['n_ecd']} clips: Pearson r = {motion['pearson']:.3f} "
              f"(r^2 = {motion['r2']:.3f}), Spearman rho = {motion['spearman']:.3f}")
    elif motion["n_ecd"]:
        print(f"\n{args.column} vs ECD: {motion['n_ecd']} clips (< {MIN_N}), no correlation")
    if args.out:
        write_csv(args.out, table, columns)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.plot:
        from .research.plot import import_pyplot, plot_group_violins

        fig = plot_group_violins(records, args.column)
        fig.savefig(args.plot, dpi=120)
        import_pyplot().close(fig)
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.against:
        other = _read_scores(args.against)
        try:
            agree = agreement_between(records, other, args.column, by=args.by)
        except (KeyError, ValueError) as exc:
            raise UsageError(exc.args[0]) from None
        keys = "groups" if args.by == "group" else "clips"
        if agree["n"] >= MIN_N:
            print(f"agreement by {args.by} with {' '.join(args.against)} over {agree['n']} matched {keys}: "
                  f"Spearman rho = {agree['spearman']:.4f}, Kendall tau-b = {agree['kendall_tau']:.4f}, "
                  f"Pearson r = {agree['pearson']:.4f}")
        else:
            print(f"agreement by {args.by} with {' '.join(args.against)}: {agree['n']} matched {keys} "
                  f"(< {MIN_N}), no correlation")
        if args.by == "group":  # the paper's Table 3: each variant's group values and ranks
            ranking = ranking_table({" ".join(args.scores): records, " ".join(args.against): other}, args.column)
            print(f"\nranking by group mean of {args.column} (rank 1 = lowest):\n{format_ranking(ranking)}")
        if agree["unmatched"]:
            print(f"{len(agree['unmatched'])} unmatched: {', '.join(agree['unmatched'][:10])}"
                  + (" ..." if len(agree["unmatched"]) > 10 else ""), file=sys.stderr)
    return EXIT_OK


def _register_calibrate(sub) -> None:
    cal = sub.add_parser("calibrate", help="fit a calibration (mu, sigma, z bounds, PC1 weights) on scores CSVs",
                         description="Fit a calibration on per-clip tables and report its k-fold stability "
                                     "(docs/semantics.md §5.5).")
    cal.add_argument("scores", nargs="+", help="per-clip tables (CSV or .parquet) from `sgc-jax score --out`")
    algorithm = cal.add_argument_group("algorithm")
    algorithm.add_argument("--by", choices=("clip", "group"), default="clip",
                           help="fit on clips (default), or on per-group means (the paper's way; "
                                "docs/semantics.md §5.5)")
    algorithm.add_argument("--folds", type=int, default=5,
                           help="k of the k-fold weight stability (default 5; 0: skip; above the number of "
                                "clips: leave-one-out)")
    algorithm.add_argument("--seed", type=int, default=0, help="fold shuffling seed (default 0)")
    algorithm.add_argument("--floor-band", type=float, default=0.0,
                           help="fit an excess calibration: the pose components above this many times their noise "
                                "floors (default 0: the components as they are; sgc-spec-2026 was fitted with 1.25; "
                                "docs/semantics.md §5.1, §5.5)")
    output = cal.add_argument_group("output")
    output.add_argument("--out", help="calibration JSON to write (use with `score --calibration`; without it the "
                        "calibration is printed, not kept)")
    output.add_argument("--name", default="custom", help="name stored in the calibration")
    output.add_argument("--rescored", help="also write the input rows re-scored with the new calibration")
    cal.set_defaults(func=cmd_calibrate)


def _register_rescore(sub) -> None:
    res = sub.add_parser("rescore", help="recompute sgc of scores CSVs under another calibration (no geometry)",
                         description="Recompute sgc, its interval and sgc_floor from the stored components under "
                                     "another calibration (docs/semantics.md §5).")
    res.add_argument("scores", nargs="+", help="per-clip tables (CSV or .parquet) from `sgc-jax score --out`")
    res.add_argument("--calibration", required=True,
                     help="(required) shipped calibration name or a calibration JSON file")
    res.add_argument("--out", help="re-scored CSV (default: print the table)")
    res.set_defaults(func=cmd_rescore)


def _register_compare(sub) -> None:
    cmp_ = sub.add_parser("compare", help="per-group / per-clip tables, ECD dependence, agreement of two files",
                          description="Rank groups or clips with bootstrap CIs, their dependence on camera "
                                      "dynamics (ECD) and the agreement of two scorings (docs/semantics.md §6.5).")
    cmp_.add_argument("scores", nargs="+", help="per-clip tables, CSV or .parquet (read together as one corpus)")
    cmp_.add_argument("--by", choices=("group", "clip"), default="group",
                      help="one row per group (default) or per clip")
    cmp_.add_argument("--column", default="sgc", help="score column to summarise (default: sgc)")
    cmp_.add_argument("--against", nargs="+", help="other per-clip tables: rank agreement per clip or group mean")
    cmp_.add_argument("--boot", type=int, default=2000, help="bootstrap resamples for the 95%% CI (default 2000)")
    cmp_.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    cmp_.add_argument("--out", help="write the table as CSV")
    cmp_.add_argument("--plot", help="violins of the column per group, clips coloured by ECD (PNG/PDF; needs matplotlib)")
    cmp_.set_defaults(func=cmd_compare)


def cmd_import(args: argparse.Namespace) -> int:
    import warnings

    from .adapters import import_clip
    from .io.clip import save_clip

    inputs = [p for p in (args.cameras, args.depth, args.da3, args.tracks, args.masks, args.frames) if p]
    guard_outputs(inputs, out=args.out if args.out.endswith(".npz") else args.out + ".npz")
    if args.depth is not None and args.depth_kind is None and not args.reference_compat:
        raise UsageError("--depth-kind disparity|metric is required: disparity for Video Depth Anything's relative "
                         "models, metric for its metric ones (or --reference-compat, the SGC authors' pipeline)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            clip = import_clip(
                cameras=args.cameras, depth=args.depth, da3=args.da3, tracks=args.tracks, masks=args.masks,
                frames=args.frames, da3_min_conf=args.da3_min_conf,
                depth_kind=args.depth_kind, depth_scale=args.depth_scale, depth_key=args.depth_key, size=args.size,
                vggt_mode=args.vggt_mode, vggt_source_size=args.vggt_source_size, track_size=args.track_size,
                vis_threshold=args.vis_threshold, reference_compat=args.reference_compat,
                align_depth=not args.no_align_depth, line_ratio=args.leave_out_line_tracks,
                frame_step=args.frame_step, max_depth=args.max_depth, depth_edge_ratio=args.depth_edge_ratio,
                per_frame_intrinsics=args.per_frame_intrinsics, mask_grow_px=args.mask_grow,
                depth_resize=args.depth_resize, clip_id=args.clip_id or Path(args.out).stem, group=args.group)
        except (OSError, ValueError) as exc:  # EstimatorFormatError and ClipFormatError are ValueErrors
            raise UsageError(str(exc)) from None
    for warning in caught:
        print(f"sgc-jax import: warning: {warning.message}", file=sys.stderr)
    path = save_clip(args.out, clip)
    record = clip.meta["import"]
    for key in ("intrinsics", "depth_rule", "track_visibility", "masks"):
        print(f"sgc-jax import: {key.replace('_', ' ')}: {record[key]}", file=sys.stderr)
    if "frame_step" in record:
        step = record["frame_step"]
        print(f"sgc-jax import: frame step {step['step']}: {step['frames_kept']} of {step['of']} frames kept, "
              "each pair that far apart", file=sys.stderr)
    if "max_depth" in record:
        print(f"sgc-jax import: depth beyond {record['max_depth']['limit']:g} invalid: "
              f"{record['max_depth']['invalid_frac']:.0%} of the valid depth", file=sys.stderr)
    if "depth_ramps" in record:
        print(f"sgc-jax import: depth on ramps at edges spanning more than {record['depth_ramps']['ratio']:g}x invalid: "
              f"{record['depth_ramps']['invalid_frac']:.0%} of the valid depth", file=sys.stderr)
    if "line_tracks" in record:
        print(f"sgc-jax import: tracks on lines left out: {record['line_tracks']['left_out']:.0%} of the visible ones",
              file=sys.stderr)
    H, W = clip.image_size
    print(f"wrote {path}: {clip.n_frames} frames, {H}x{W}, {clip.n_tracks} tracks per pair"
          + (" (reference-compat)" if args.reference_compat else ""), file=sys.stderr)
    return EXIT_OK


def cmd_pack(args: argparse.Namespace) -> int:
    import warnings

    from .io.clip import save_batch
    from .io.loading import discover_clips

    keep_all = SGCConfig(max_tracks=2**31 - 1)  # a batch file keeps every track; scoring sub-samples
    guard_outputs(clip_input_files(args.clips), out=args.out if args.out.endswith(".npz") else args.out + ".npz")
    try:
        entries = discover_clips(list(args.clips), keep_all)
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    clips, failed = [], 0
    for entry in entries:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                clips.append(entry.load())
            except (OSError, ValueError, KeyError) as exc:
                failed += 1
                print(f"sgc-jax pack: error: {entry.origin}: {exc}", file=sys.stderr)
        for warning in caught:
            print(f"sgc-jax pack: warning: {entry.origin}: {warning.message}", file=sys.stderr)
    if failed and not args.skip_errors:
        print(f"sgc-jax pack: {failed} clip(s) failed to load; nothing written (--skip-errors packs the rest)",
              file=sys.stderr)
        return EXIT_SOME_FAILED
    if not clips:
        print("sgc-jax pack: no clip to pack", file=sys.stderr)
        return EXIT_SOME_FAILED
    path = save_batch(args.out, clips)
    print(f"packed {len(clips)} clip(s) into {path}" + (f"; {failed} skipped" if failed else ""), file=sys.stderr)
    return EXIT_SOME_FAILED if failed else EXIT_OK


def cmd_validate(args: argparse.Namespace) -> int:
    from .io.loading import validate_paths

    if not clip_input_files(args.paths):  # as `score` does: nothing to check is a usage error
        raise UsageError(f"no .npz clips in {' '.join(args.paths)}")
    try:
        reports = validate_paths(list(args.paths))
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    for report in reports:
        for line in report.lines(show_info=args.verbose):
            print(line)
    errors = sum(not r.ok for r in reports)
    warned = sum(any(p.severity == "warning" for p in r.problems) for r in reports)
    print(f"{len(reports)} clip(s) checked: {errors} with errors, {warned} with warnings", file=sys.stderr)
    return EXIT_SOME_FAILED if errors or (args.strict and warned) else EXIT_OK


def _add_depth_options(conversion) -> None:
    """The import's options for the depth's far backdrop, edges and size (docs/semantics.md §1.5)."""
    conversion.add_argument("--max-depth", type=float, metavar="Z",
                            help="depth beyond Z (the clip's units, after conversion) is invalid: a sky or far "
                                 "backdrop, which `sgc-jax validate` warns of (far_backdrop; docs/semantics.md §3.1)")
    conversion.add_argument("--depth-edge-ratio", type=float, metavar="R", nargs="?", const=DEPTH_EDGE_RATIO,
                            help=f"depth invalid on the ramps at edges whose 3x3 neighbourhood spans more than R (largest "
                                 f"/ smallest; R {DEPTH_EDGE_RATIO:g} when given alone): a depth network's enlarged output, "
                                 "whose edges are ramps of points on no surface, which `sgc-jax validate` warns of "
                                 "(smooth_depth_edges) and the depth check reads as error (docs/semantics.md §3.6)")
    conversion.add_argument("--depth-resize", choices=DEPTH_RESIZES, default="nearest",
                            help="how depth maps smaller than the clip grid are brought up to it (default nearest: no "
                                 "depth mixed, but in blocks, whose steps lift consistent clips and which `sgc-jax "
                                 "validate` warns of, depth_in_blocks); bilinear: within valid depth, calm, but it sees "
                                 "depth inconsistencies under 2 px tracker noise less often (docs/semantics.md §1.5, "
                                 "\"Depth maps of another size\")")


def _register_import(sub) -> None:
    imp = sub.add_parser(
        "import", help="estimator outputs (VGGT + Video Depth Anything or Depth Anything 3, DELTA or CoTracker3, "
                       "SegAnyMo) -> clip .npz",
        usage="sgc-jax import (--cameras NPZ --depth NPZ --depth-kind {disparity,metric} | --da3 NPZ) --tracks PATH "
              "--out NPZ [--masks DIR] [--frames PATH] [options]",
        description="Turn one clip's estimator outputs into a clip file, each array brought to the clip grid by "
                    "its estimator's rule (docs/semantics.md §1.5).")
    inputs = imp.add_argument_group("depth and cameras: VGGT with Video Depth Anything, or Depth Anything 3")
    inputs.add_argument("--cameras", metavar="NPZ",
                        help="VGGT predictions .npz with extrinsic (S,3,4), intrinsic (S,3,3)")
    inputs.add_argument("--depth", metavar="NPZ", help="Video Depth Anything *_depths.npz (array 'depths')")
    inputs.add_argument("--depth-kind", choices=("disparity", "metric"),
                        help="disparity: VDA relative models (depth = scale / disparity); metric: metric models "
                             "(required with --depth unless --reference-compat)")
    inputs.add_argument("--da3", metavar="NPZ",
                        help="Depth Anything 3 results.npz (export_format 'npz' or 'mini_npz'): depth, extrinsics "
                             "and intrinsics of an any-view or nested model, in place of --cameras and --depth")
    inputs = imp.add_argument_group("required")
    inputs.add_argument("--tracks", required=True, metavar="PATH",
                        help="DELTA folder of per-pair {a}_{a}.npy/{a}_{b}.npy, or dense coords/vis/conf .pkl/.npz; "
                             "or CoTracker3 pred_tracks (T,N,2) and pred_visibility (T,N) in an .npz or .pt "
                             "(an .npy: pred_tracks alone)")
    inputs.add_argument("--out", required=True, metavar="NPZ", help="clip .npz to write")
    inputs = imp.add_argument_group("optional inputs")
    inputs.add_argument("--masks", metavar="DIR", help="SegAnyMo folder of palette PNGs (absent: nothing moves)")
    inputs.add_argument("--frames", metavar="PATH", help="frames folder or video file (names frames; optional RGB for plots)")
    conversion = imp.add_argument_group("conversion")
    conversion.add_argument("--depth-scale", type=float,
                            help="depth = scale / disparity, or scale * metric (default 1; unused when the disparity "
                                 "is aligned to VGGT's depth)")
    conversion.add_argument("--depth-key", default="depths", help="array name in the depth file (default: depths)")
    conversion.add_argument("--size", help="clip grid HxW (default: frames, else masks, else depth size)")
    conversion.add_argument("--vggt-mode", choices=VGGT_MODES, default="crop",
                            help="VGGT load_and_preprocess_images mode (default: crop)")
    conversion.add_argument("--vggt-source-size", help="HxW of the frames VGGT saw, when not the clip grid")
    conversion.add_argument("--track-size", help="HxW of the frames the tracker saw, when not the clip grid")
    conversion.add_argument("--da3-min-conf", type=float,
                            help="Depth Anything 3: depth of confidence below this is invalid (default: all kept)")
    conversion.add_argument("--no-align-depth", action="store_true",
                            help="keep depth = scale / disparity with shift 0. By default, with --depth-kind disparity "
                                 "and a 'depth' map in --cameras, the disparity's scale and shift are fitted (robustly, "
                                 "over static pixels of above-median VGGT confidence) to VGGT's depth, so depth and "
                                 "camera translations share units; meta['import']['depth_alignment'] records the fit "
                                 "or what was assumed")
    conversion.add_argument("--vis-threshold", type=float,
                            help="visibility above this is visible (default: the tracker's own, DELTA "
                                 f"{DELTA_VIS_THRESHOLD:g}, CoTracker3 0.6 where its visibility is not boolean)")
    conversion.add_argument("--leave-out-line-tracks", type=float, nargs="?", const=LINE_RATIO, default=None,
                            metavar="RATIO",
                            help="make unusable the tracks whose first frame's image structure is a line "
                                 f"(structure tensor eigenvalue ratio below RATIO, default {LINE_RATIO:g}), which a "
                                 "tracker like LK can slide along; needs --frames (docs/semantics.md §1.7)")
    conversion.add_argument("--frame-step", type=int, default=1, metavar="K",
                            help="keep frames 0, K, 2K, ... so each pair is K frames apart (default 1: every frame); "
                                 "for long clips whose frames move little, tracked at full rate by a long-range "
                                 "tracker (DELTA dense, CoTracker3) (docs/semantics.md §1.5)")
    conversion.add_argument("--per-frame-intrinsics", action="store_true",
                            help="keep the cameras' K of every frame (a video that zooms). By default the clip gets "
                                 "one K, the median of the frames': an estimator's focal lengths scatter from frame to "
                                 "frame, which the depth check reads as inconsistency (docs/semantics.md §1.5)")
    _add_depth_options(conversion)
    conversion.add_argument("--mask-grow", type=int, default=0, metavar="PX",
                            help="grow each frame's moving-object mask by PX pixels (default 0): a segmenter that falls "
                                 "short of a mover's outline leaves a band of it static, which the score reads as "
                                 "inconsistency; about 2.5 %% of the image diagonal (docs/semantics.md §1.5, \"Motion masks\")")
    conversion.add_argument("--reference-compat", action="store_true",
                            help="the SGC authors' choices (docs/semantics.md §1.5): K at VGGT's 518-px scale, depth = VDA / 1000, "
                                 "visibility not thresholded; the paper calibration assumes them")
    output = imp.add_argument_group("output")
    output.add_argument("--clip-id", help="clip id (default: the output file name)")
    output.add_argument("--group", default="", help="group stored in meta (e.g. the generator's name)")
    imp.set_defaults(func=cmd_import)


def _register_pack(sub) -> None:
    pack = sub.add_parser("pack", help="stack clip .npz files into one batch file (docs/semantics.md §1.3)",
                          description="Stack clip files into one batch .npz: each clip's arrays padded to the "
                                      "largest (T, H, W, P), its true sizes and clip id kept (docs/semantics.md "
                                      "§1.3). `score` reads a batch file as it reads a directory of its clips; "
                                      "one file moves and reads faster than thousands. Clips are validated as "
                                      "they are loaded: a broken one stops the pack unless --skip-errors.")
    pack.add_argument("clips", nargs="+", help="clip .npz files, directories, globs or URLs")
    pack.add_argument("--out", required=True, help="(required) batch .npz to write")
    pack.add_argument("--skip-errors", action="store_true", help="pack the loadable clips when some fail")
    pack.set_defaults(func=cmd_pack)


def _register_validate(sub) -> None:
    val = sub.add_parser("validate", help="dry run: check clip / batch files, one line per problem",
                         description="Check clip and batch files as the loader would, and their content "
                                     "(docs/semantics.md §1.4, §1.6); nothing is scored.")
    val.add_argument("paths", nargs="+", help=CLIP_INPUTS_HELP)
    val.add_argument("-v", "--verbose", action="store_true", help="also print info lines (depth range, mask coverage)")
    val.add_argument("--strict", action="store_true", help="exit non-zero on warnings too")
    val.set_defaults(func=cmd_validate)


def _csv_list(text: str, convert=str) -> list:
    try:
        return [convert(item.strip()) for item in text.split(",") if item.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not a comma-separated list: {text!r} ({exc})") from exc


def cmd_perturb(args: argparse.Namespace) -> int:
    from .research.study import check_kinds, check_severities, sensitivity_study

    if args.plot:  # fail before the (long) study when matplotlib is missing
        _require_matplotlib()
    inputs = clip_input_files(args.paths)
    if not inputs:
        raise UsageError(f"no .npz clips in {' '.join(args.paths)}")
    guard_outputs([*inputs, args.config, _calibration_file(args.calibration)], out=args.out, summary=args.summary,
                  plot=args.plot)
    config, calibration = _config_and_calibration(args)
    try:
        check_kinds(args.kinds), check_severities(args.severities)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.chunk_size < 1:
        raise UsageError(f"--chunk-size must be >= 1, got {args.chunk_size}")
    _use_compilation_cache(args.engine)
    study = sensitivity_study(list(args.paths), args.kinds, args.severities, config=config, calibration=calibration,
                              engine=args.engine, perturb_seed=args.perturb_seed, progress=_progress(args),
                              chunk_size=args.chunk_size)
    failed = sorted({r["base"] for r in study.rows if r["status"] == "error" and r["severity"] == 0})
    for base in failed:
        print(f"sgc-jax perturb: {base}: not scored", file=sys.stderr)
    if args.out:
        study.to_csv(args.out, summary_path=args.summary)
        print(f"wrote {args.out}" + (f" and {args.summary}" if args.summary else ""), file=sys.stderr)
    if args.plot:
        from .research.plot import import_pyplot, plot_sensitivity

        fig = plot_sensitivity(study)
        fig.savefig(args.plot, dpi=120)
        import_pyplot().close(fig)
        print(f"wrote {args.plot}", file=sys.stderr)
    print(study.table())
    return EXIT_SOME_FAILED if failed else EXIT_OK


def _register_perturb(sub) -> None:
    from .research.perturb import MASK_CORRUPTIONS, PERTURBATIONS

    p = sub.add_parser("perturb", help="sensitivity study: score clips under perturbations of growing severity",
                       description="Score every clip under every perturbation kind and severity; print the mean "
                                   "SGC and components per kind and severity and Spearman rho vs severity "
                                   "(docs/semantics.md §6.4).")
    p.add_argument("paths", nargs="+", help=CLIP_INPUTS_HELP)
    study = p.add_argument_group("study")
    study.add_argument("--kinds", type=_csv_list, default=list(PERTURBATIONS),
                       help=f"comma-separated, from {','.join(PERTURBATIONS + MASK_CORRUPTIONS)} "
                            f"(default: {','.join(PERTURBATIONS)})")
    study.add_argument("--severities", type=lambda s: _csv_list(s, float), default=[0.0, 0.25, 0.5, 0.75, 1.0],
                       help="comma-separated values in [0, 1] (default: 0,0.25,0.5,0.75,1)")
    study.add_argument("--perturb-seed", type=int, default=0, help="seed of the perturbations (default 0)")
    study.add_argument("--chunk-size", type=int, default=256,
                       help="clips perturbed and scored per engine call (default 256)")
    output = p.add_argument_group("output")
    output.add_argument("--out", help="one row per clip, kind and severity: base, kind, severity, "
                        "the columns of docs/semantics.md §4, rel_change")
    output.add_argument("--summary", help="per kind and severity means (CSV)")
    output.add_argument("--plot", help="figure of SGC and components vs severity (PNG/PDF; needs matplotlib)")
    _add_algorithm_flags(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (shown on a terminal)")
    p.set_defaults(func=cmd_perturb)


# One registrar per subcommand, in the order ``sgc-jax --help`` lists them.
SUBCOMMANDS = (
    _register_score,
    _register_demo,
    _register_synth,
    _register_calibrate,
    _register_rescore,
    _register_compare,
    _register_import,
    _register_pack,
    _register_validate,
    _register_perturb,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sgc-jax", description="Spatial Geometric Consistency scores",
                                     epilog=EXIT_CODES_HELP)
    parser.add_argument("--version", action="version", version=f"sgc-jax {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for register in SUBCOMMANDS:
        register(sub)
    for name, command in sub.choices.items():
        examples = "\n".join(f"  {line}" for line in EXAMPLES[name])
        command.epilog = f"example{'s' if len(EXAMPLES[name]) > 1 else ''}:\n{examples}\n\n" + textwrap.fill(EXIT_CODES_HELP)
        command.formatter_class = argparse.RawDescriptionHelpFormatter  # the examples' lines kept as written
        command.description = textwrap.fill(command.description) if command.description else None
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns its exit code (argparse itself exits 2 on malformed arguments)."""
    parser = build_parser()
    args, unrecognized = parser.parse_known_args(argv)
    if unrecognized:  # argparse's own message, with the likely cause where the words are not options
        words = " ".join(unrecognized)
        hint = "" if args.command != "perturb" or any(word.startswith("-") for word in unrecognized) else (
            "; its list options take one comma-separated word (e.g. --severities 0.25,0.5 --kinds warp,squeeze)")
        parser.error(f"unrecognized arguments: {words}{hint}")
    try:
        with warnings.catch_warnings():
            warnings.showwarning = clip_warnings_as_lines(f"sgc-jax {args.command}")
            return args.func(args)
    except (UsageError, MissingExtraError) as exc:
        print(f"sgc-jax {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"sgc-jax {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # stdout closed early (`| head`): stop quietly, as the Python docs advise
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_SOME_FAILED
    except Exception:  # not bad input (that is reported per clip or as a usage error): a bug, shown as one
        traceback.print_exc()
        print(f"sgc-jax {args.command}: internal error in sgc_jax {__version__}; please report it with the "
              "traceback above", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""The sgc-jax command line, run as a real process on real files."""

import csv
import dataclasses
import json
import subprocess
import sys
import typing

import pytest
from scenes import TINY
from test_bad_input import CONTROLS, write_controls, write_every_broken_kind

from sgc_jax import Calibration, SGCConfig, save_clip, score_batch
from sgc_jax.cli import (
    EXIT_INTERNAL,
    EXIT_OK,
    EXIT_SOME_FAILED,
    EXIT_USAGE,
    _config_and_calibration,
    build_parser,
    main,
)
from sgc_jax.config import cli_flag
from sgc_jax.research.synth import synth_clip

CLI = [sys.executable, "-m", "sgc_jax.cli"]


def run(*args, cwd=None):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=600)


def test_score_reports_broken_clip_and_scores_the_others(tmp_path):
    clips = tmp_path / "clips"
    for seed in (0, 1):
        save_clip(clips / f"good{seed}.npz", synth_clip(seed=seed, clip_id=f"good{seed}", **TINY))
    (clips / "broken.npz").write_bytes(b"not an npz file")
    out, pairs = tmp_path / "scores.csv", tmp_path / "pairs.csv"
    proc = run("score", clips, "--out", out, "--pairs", pairs, "--engine", "reference", "-q")
    assert proc.returncode == 1, proc.stderr  # finished, with an error row
    assert "broken" in proc.stderr and "Traceback" not in proc.stderr
    rows = {r["clip_id"]: r for r in csv.DictReader(out.open())}
    assert rows["broken"]["status"] == "error" and rows["broken"]["reason"]
    assert rows["good0"]["status"] in ("ok", "partial") and float(rows["good0"]["sgc"]) >= 0
    pair_rows = list(csv.DictReader(pairs.open()))
    assert len(pair_rows) == 4 and {"pair", "n_tracks", "n_regions", "n_poses"} <= set(pair_rows[0])


def test_a_clips_warning_is_one_line_naming_the_command_and_the_clip(tmp_path):
    clip = synth_clip(seed=0, clip_id="percent", **TINY)
    save_clip(tmp_path / "percent.npz", dataclasses.replace(clip, track_conf=100.0 * clip.track_conf))
    for prefix, read_in in (("sgc-jax score", "threads"), ("sgc-jax", "processes")):
        proc = run("score", tmp_path / "percent.npz", "--engine", "reference", "--read-in", read_in, "-q")
        [line] = [line for line in proc.stderr.splitlines() if "track_conf" in line]
        assert line.startswith(f"{prefix}: clip 'percent': warning: track_conf:") and "sigmoid" in line, read_in
        assert "ClipWarning" not in proc.stderr and "clip_from_arrays" not in proc.stderr, read_in
        assert "1 with content warnings" in proc.stderr.splitlines()[-1], read_in


def test_score_exits_non_zero_when_a_clip_could_not_be_scored(tmp_path):
    (tmp_path / "broken.npz").write_bytes(b"junk")
    proc = run("score", tmp_path / "broken.npz", "--engine", "reference", "-q")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    missing = run("score", tmp_path / "nothing_here", "--engine", "reference")
    assert missing.returncode == 2 and "nothing_here" in missing.stderr


def test_a_piped_score_draws_no_progress_bar_between_its_lines(tmp_path):
    save_clip(tmp_path / "a.npz", synth_clip(seed=0, clip_id="a", **TINY))
    proc = run("score", tmp_path / "a.npz", "--engine", "reference")  # stderr a pipe, no -q
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr and "clip/s" not in proc.stderr
    assert proc.stderr.splitlines()[-1].startswith("1 clip(s):")


def test_synth_writes_the_demo_corpus_and_demo_prints_units_and_intervals(tmp_path):
    proc = run("synth", "--out", tmp_path / "demo")
    assert proc.returncode == 0 and len(list((tmp_path / "demo").glob("*.npz"))) == 8
    demo = run("demo", "-q")  # the JAX engine: the demo bucket's programs come from the suite's cache
    assert demo.returncode == 0, demo.stderr
    assert "rigid-a" in demo.stdout and "sgc_lo" in demo.stdout and "(% of D)²" in demo.stdout  # a row of units
    assert "90% interval" in demo.stdout
    assert "for this run only (--out DIR keeps them)" in demo.stderr


def test_version_names_the_package_version():
    from sgc_jax import __version__

    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"sgc-jax {__version__}"


def test_every_option_of_every_command_has_help_text():
    import argparse

    from sgc_jax.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    missing = [f"{name} {'/'.join(action.option_strings)}" for name, command in commands.items()
               for action in command._actions
               if action.option_strings and not isinstance(action, argparse._HelpAction) and not action.help]
    assert missing == []


def test_validate_and_score_treat_an_empty_folder_alike(tmp_path):
    codes = {command: run(command, tmp_path).returncode for command in ("validate", "score")}
    assert codes == {"validate": 2, "score": 2}


# ----------------------------------------------------------------------------- bad input, exit codes (docs/semantics.md §8)


def test_a_folder_of_broken_inputs_prints_no_traceback_in_any_command(tmp_path):
    folder = tmp_path / "clips"
    folder.mkdir()
    write_controls(folder)
    n_broken = write_every_broken_kind(folder)
    out = tmp_path / "scores.csv"
    procs = {
        "score": run("score", folder, "--engine", "reference", "-q", "--out", out),
        "validate": run("validate", folder),
        "pack": run("pack", folder, "--skip-errors", "--out", tmp_path / "packed.npz"),
        "perturb": run("perturb", folder, "--engine", "reference", "--kinds", "warp", "--severities", "0,1", "-q"),
    }
    for command, proc in procs.items():
        assert "Traceback" not in proc.stdout + proc.stderr, (command, proc.stderr[-3000:])
        assert proc.returncode == EXIT_SOME_FAILED, (command, proc.stderr[-3000:])
    rows = list(csv.DictReader(out.open()))
    assert sum(r["status"] == "error" for r in rows) == n_broken
    assert all(r["status"] != "error" for r in rows if r["clip_id"].startswith("ctrl"))


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """A clip file and its scores CSV."""
    folder = tmp_path_factory.mktemp("scored")
    save_clip(folder / "clip.npz", CONTROLS[0])
    score_batch(folder / "clip.npz", engine="reference", progress=False).to_csv(folder / "scores.csv")
    return folder / "clip.npz", folder / "scores.csv"


def test_exit_codes_are_as_documented(scored, tmp_path):
    clip, table = scored
    assert run("score", clip, "--engine", "reference", "-q").returncode == EXIT_OK
    assert run("rescore", table, "--calibration", "sgc-spec-2026").returncode == EXIT_OK
    (tmp_path / "a.npy").write_bytes(b"x")
    usage = {
        "a CSV given to score": (run("score", table), "rescore"),
        "a clip given to compare": (run("compare", clip), "score the clips first"),
        "an .npy given to validate": (run("validate", tmp_path / "a.npy"), "named arrays"),
        "a calibration fitted for the other semantics": (run("rescore", table, "--calibration", "sgc-paper-2026"),
                                                         "sgc-spec-2026"),
        "nothing found": (run("score", tmp_path / "none"), "none"),
        "an unknown calibration": (run("score", clip, "--calibration", "nope"), "nope"),
        "a malformed option": (run("score", clip, "--partition", "hexagons"), "invalid choice"),
        "a negative lane count": (run("score", clip, "--lanes", "-1"), "--lanes"),
        "a negative reader count": (run("score", clip, "--readers", "-1"), "--readers"),
    }
    for case, (proc, words) in usage.items():
        assert proc.returncode == EXIT_USAGE and words in proc.stderr, (case, proc.stderr)
        assert "Traceback" not in proc.stderr and proc.stdout == "", case


def test_an_unexpected_exception_is_an_internal_error_with_its_traceback(scored, monkeypatch, capsys):
    from sgc_jax.engines import reference

    def broken_engine(clip, config):
        raise RuntimeError("a bug in the engine")

    monkeypatch.setattr(reference, "score_pairs", broken_engine)
    assert main(["score", str(scored[0]), "--engine", "reference", "-q"]) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert "Traceback" in err and "a bug in the engine" in err and "internal error" in err


def _overwrite_attempts(clip, table, tmp_path):
    link = tmp_path / "link.csv"
    link.symlink_to(table)
    folder = tmp_path / "a_folder"
    folder.mkdir()
    calibration = tmp_path / "calibration.json"
    Calibration.load("sgc-spec-2026").save(calibration)
    return {  # case: (arguments, the input that must survive, words of the refusal)
        "score a CSV onto itself": (("score", table, "--out", table), table, "not a clip file"),
        "score onto its clip": (("score", clip, "--out", clip), clip, "would be overwritten"),
        "score, pairs onto its clip": (("score", clip, "--pairs", clip), clip, "would be overwritten"),
        "score, one file for both tables": (("score", clip, "--out", tmp_path / "x.csv", "--pairs", tmp_path / "x.csv"),
                                            clip, "same file as --out"),
        "score into a directory": (("score", clip, "--out", folder), clip, "a directory"),
        "score onto its calibration file": (("score", clip, "--calibration", calibration, "--out", calibration),
                                            calibration, "would be overwritten"),
        "rescore onto itself": (("rescore", table, "--calibration", "sgc-spec-2026", "--out", table), table,
                                "would be overwritten"),
        "rescore through a link": (("rescore", table, "--calibration", "sgc-spec-2026", "--out", link), table,
                                   "would be overwritten"),
        "compare onto itself": (("compare", table, "--out", table), table, "would be overwritten"),
        "calibrate onto its table": (("calibrate", table, "--rescored", table), table, "would be overwritten"),
        "pack onto its clip": (("pack", clip, "--out", clip), clip, "would be overwritten"),
        "perturb onto its clip": (("perturb", clip, "--summary", clip), clip, "would be overwritten"),
        "import onto its cameras": (("import", "--cameras", clip, "--depth", table, "--tracks", folder, "--out", clip),
                                    clip, "would be overwritten"),
    }


def test_an_output_that_names_an_input_is_refused_and_the_input_kept(scored, tmp_path, capsys):
    # through main() in this process: a refusal is argument logic; the real process, its exit codes
    # and stderr, are test_exit_codes_are_as_documented's
    clip, table = scored
    for case, (args, kept, words) in _overwrite_attempts(clip, table, tmp_path).items():
        before = kept.read_bytes()
        code = main([str(a) for a in args])
        stderr = capsys.readouterr().err
        assert code == EXIT_USAGE and words in stderr, (case, stderr)
        assert "Traceback" not in stderr and kept.read_bytes() == before, case


# ----------------------------------------------------------------------------- configuration options, --config (docs/semantics.md §2, §8)


def non_default_values() -> dict:
    """A valid value other than the default for every SGCConfig field."""
    hints = typing.get_type_hints(SGCConfig)
    values = {}
    for f in dataclasses.fields(SGCConfig):
        kind = hints[f.name]
        if f.metadata.get("choices"):
            values[f.name] = next(c for c in reversed(f.metadata["choices"]) if c != f.default)
        elif kind is bool or bool in typing.get_args(kind):
            values[f.name] = True if f.default is None else not f.default
        else:
            values[f.name] = f.default + 1 if kind is int else f.default / 2  # every float field is > 0
    return values


def as_options(values: dict) -> list[str]:
    options = []
    for f in dataclasses.fields(SGCConfig):
        value, flag = values[f.name], cli_flag(f)
        options += [flag if value else "--no-" + flag[2:]] if isinstance(value, bool) else [flag, str(value)]
    return options


def configured(*argv, command="score") -> SGCConfig:
    return _config_and_calibration(build_parser().parse_args([command, "clip.npz", *map(str, argv)]))[0]


@pytest.mark.parametrize("command", ["score", "perturb"])
def test_every_field_is_set_by_its_option_and_only_when_given(command):
    values = non_default_values()
    assert configured(command=command) == SGCConfig()
    assert configured(*as_options(values), command=command) == SGCConfig(**values)
    assert configured("--no-mos", "--no-global-pose", "--no-quality-rule", "--align-scale", "--compat", "authors",
                      "--seed", "3", "--partition", "grid") == SGCConfig(
        use_mos=False, global_pose=False, quality_rule=False, align_scale=True, compat="authors", seed=3,
        partition="grid")


def test_config_file_sets_fields_and_options_override_it(tmp_path):
    values = non_default_values()
    path = tmp_path / "config.json"
    path.write_text(json.dumps(values))
    assert configured("--config", path) == SGCConfig(**values)
    assert configured("--config", path, "--inlier-px", "9", "--mos") == SGCConfig(**{**values, "inlier_px": 9.0,
                                                                                        "use_mos": True})
    path.write_text(json.dumps(SGCConfig().to_dict()))
    assert configured("--config", path) == SGCConfig()
    toml = tmp_path / "config.toml"
    toml.write_text('inlier_px = 6\npartition = "grid"\nuse_mos = false\n')
    assert configured("--config", toml, command="perturb") == SGCConfig(inlier_px=6.0, partition="grid", use_mos=False)


@pytest.mark.parametrize("content, words", [
    ('{"inlier": 6}', "unknown SGCConfig field(s) ['inlier']"),
    ('{"k_seg": "10"}', "k_seg must be int, got '10'"),
    ('{"k_seg": true}', "k_seg must be int, got True"),
    ('{"use_mos": 0}', "use_mos must be bool, got 0"),
    ('{"confidence": 2}', "confidence must be in (0, 1)"),
    ('[1]', "expected an object of SGCConfig fields"),
    ('{"k_seg": ', "not a JSON file"),
])
def test_a_bad_config_file_is_a_one_line_usage_error(scored, tmp_path, capsys, content, words):
    path = tmp_path / "config.json"
    path.write_text(content)
    for command in ("score", "perturb"):
        assert main([command, str(scored[0]), "--engine", "reference", "--config", str(path)]) == EXIT_USAGE
        err = capsys.readouterr().err
        assert err.startswith(f"sgc-jax {command}: error: ") and err.count("\n") == 1 and words in err, err


def test_config_file_is_an_input_that_out_cannot_overwrite(scored, tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"seed": 1}')
    proc = run("score", scored[0], "--config", path, "--out", path)
    assert proc.returncode == EXIT_USAGE and "would be overwritten" in proc.stderr, proc.stderr
    assert path.read_text() == '{"seed": 1}'
    missing = run("perturb", scored[0], "--config", tmp_path / "none.json")
    assert missing.returncode == EXIT_USAGE and "none.json" in missing.stderr and "Traceback" not in missing.stderr

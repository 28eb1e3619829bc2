"""The sgc-jax command line, run as a real process on real files."""

import csv
import subprocess
import sys

from sgc_jax import save_clip
from sgc_jax.synth import synth_clip

CLI = [sys.executable, "-m", "sgc_jax.cli"]


def run(*args, cwd=None):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=600)


def test_score_reports_broken_clip_and_scores_the_others(tmp_path):
    clips = tmp_path / "clips"
    for seed in (0, 1):
        save_clip(clips / f"good{seed}.npz", synth_clip(seed=seed, clip_id=f"good{seed}", n_frames=3, height=64, width=80,
                                                        n_tracks=256, n_layers=1, static_spheres=2))
    (clips / "broken.npz").write_bytes(b"not an npz file")
    out, pairs = tmp_path / "scores.csv", tmp_path / "pairs.csv"
    proc = run("score", clips, "--out", out, "--pairs", pairs, "--engine", "reference", "-q")
    assert proc.returncode == 0, proc.stderr
    assert "broken" in proc.stderr and "Traceback" not in proc.stderr
    rows = {r["clip_id"]: r for r in csv.DictReader(out.open())}
    assert rows["broken"]["status"] == "error" and rows["broken"]["reason"]
    assert rows["good0"]["status"] in ("ok", "partial") and float(rows["good0"]["sgc"]) >= 0
    pair_rows = list(csv.DictReader(pairs.open()))
    assert len(pair_rows) == 4 and {"pair", "n_tracks", "n_regions", "n_poses"} <= set(pair_rows[0])


def test_score_exits_non_zero_when_nothing_could_be_scored(tmp_path):
    (tmp_path / "broken.npz").write_bytes(b"junk")
    proc = run("score", tmp_path / "broken.npz", "--engine", "reference", "-q")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    missing = run("score", tmp_path / "nothing_here", "--engine", "reference")
    assert missing.returncode == 2 and "nothing_here" in missing.stderr


def test_synth_and_demo(tmp_path):
    proc = run("synth", "--out", tmp_path / "demo")
    assert proc.returncode == 0 and len(list((tmp_path / "demo").glob("*.npz"))) == 8
    demo = run("demo", "--engine", "reference", "-q")
    assert demo.returncode == 0, demo.stderr
    assert "rigid-a" in demo.stdout and "sgc" in demo.stdout


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

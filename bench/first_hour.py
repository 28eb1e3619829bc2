"""A newcomer's first hour, timed: a fresh clone, the README's install, ``sgc-jax demo`` twice, then
a new Python process scoring the demo clips with ``score_batch``.

    python bench/first_hour.py [--repo .] [--work /tmp/sgc-first-hour]

Clones ``--repo`` (its committed HEAD) into ``--work``, creates a virtual environment there and
installs ``.[dev]`` as the README says, with a cache folder of its own (``XDG_CACHE_HOME``), so
nothing compiled earlier on this machine is reused. Prints each step's wall time and the lines it
wrote about compiling or loading programs.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

SCORE = ("import sgc_jax; r = sgc_jax.score_batch('demo_clips', progress=False); "
         "print(r.table(('clip_id', 'status', 'sgc')))")


def step(title: str, command: list[str], cwd: Path, env: dict) -> None:
    start = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    print(f"\n$ {' '.join(command)}   # {title}: {seconds:.1f} s, exit {done.returncode}")
    said = [line for line in done.stderr.splitlines() if "JAX program" in line or "demo clips" in line]
    for line in said + done.stdout.splitlines()[-3:]:
        print(f"  {line}")
    if done.returncode != 0:
        print(done.stderr[-2000:])
        sys.exit(done.returncode)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repo", default=str(Path(__file__).resolve().parents[1]))
    parser.add_argument("--work", default="/tmp/sgc-first-hour")
    args = parser.parse_args()
    work = Path(args.work)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SGC_JAX", "JAX_", "VIRTUAL_ENV"))}
    env["XDG_CACHE_HOME"] = str(work / "cache")
    clone = work / "sgc_jax"
    step("clone", ["git", "clone", "-q", args.repo, str(clone)], work, env)
    step("install", [sys.executable, "-m", "venv", ".venv"], clone, env)
    step("install", [".venv/bin/pip", "install", "-q", ".[dev]"], clone, env)
    step("first demo", [".venv/bin/sgc-jax", "demo"], clone, env)
    step("second demo", [".venv/bin/sgc-jax", "demo", "--out", "demo_clips"], clone, env)
    step("a new Python process", [".venv/bin/python", "-c", SCORE], clone, env)


if __name__ == "__main__":
    main()

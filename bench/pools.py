"""The command line the loader lines' benches share: a random pool of ``research.protocol`` and the
shared real clips (bench/pose_lines.py, letterbox_line.py, disparity_line.py, depth_resize.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from sgc_jax.research import protocol

REALDATA = Path(__file__).resolve().parent.parent.parent / "shared" / "realdata"


def pool_parser(doc: str, real: str = "--real") -> argparse.ArgumentParser:
    """A parser with ``--pool`` (a random pool's name), ``--scenes`` (its first N scenes), ``real`` (a
    flag: the shared real clips) and ``--realdata`` (their folder)."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pool", choices=sorted(protocol.RANDOM_POOLS))
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument(real, action="store_true")
    parser.add_argument("--realdata", type=Path, default=REALDATA)
    return parser


def need_one(parser: argparse.ArgumentParser, args: argparse.Namespace, real: str = "real") -> None:
    """Stop with the usage unless ``--pool`` or the real clips' flag was given."""
    if not (args.pool or getattr(args, real)):
        parser.error(f"give --pool or --{real.replace('_', '-')}")

"""Every output column of the demo and agreement corpora, through ``score_batch`` (both engines)
and the ``Scorer`` (one device, and two CPU devices in a subprocess), kept to prove a refactor
leaves every number bit-identical.

    python bench/identity.py --out before.npz          # on the tree before
    python bench/identity.py --out after.npz --against before.npz

Keys are ``<corpus>/<path>/<table>/<column>``: the clip and pair tables (``to_records``,
``pair_records``) of ``score_batch``, and the Scorer's (B,) outputs. Strings are kept as text.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import jax
import numpy as np

from sgc_jax import Scorer, SGCConfig, batch_of, score_batch
from sgc_jax.research.agreement import agreement_corpus
from sgc_jax.research.synth import demo_corpus

CORPORA = {"demo": demo_corpus, "agreement": agreement_corpus}


def columns(records: list[dict]) -> dict[str, np.ndarray]:
    """Records -> one array per column (text where any value is not a number)."""
    names = list(dict.fromkeys(name for record in records for name in record))
    out = {}
    for name in names:
        values = [record.get(name) for record in records]
        numeric = all(isinstance(v, (int, float, np.number, bool, type(None))) for v in values)
        out[name] = (np.array([np.nan if v is None else v for v in values], np.float64) if numeric
                     else np.array([json.dumps(v, default=str) for v in values]))
    return out


def scorer_outputs(clips, shapes: tuple, devices=None) -> dict[str, np.ndarray]:
    """The Scorer's outputs over ``clips`` in batches of 4 of the corpus's largest shape, concatenated."""
    B = 4
    T, H, W, P = shapes
    scorer = Scorer((B, T, H, W, P), SGCConfig(), devices=devices)
    parts = []
    for start in range(0, len(clips), B):
        chunk = clips[start:start + B]
        chunk = chunk + [chunk[-1]] * (B - len(chunk))
        out = scorer(batch_of(chunk, shape=(T, H, W, P)))
        parts.append({name: np.asarray(value)[:len(clips[start:start + B])] for name, value in out.items()})
    return {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


def corpus_shape(clips) -> tuple:
    return tuple(max(sizes) for sizes in zip(*[(c.n_frames, *c.image_size, c.n_tracks) for c in clips]))


def collect(paths: tuple[str, ...]) -> dict[str, np.ndarray]:
    kept = {}
    for corpus, make in CORPORA.items():
        clips = make()
        if "batch" in paths:
            for engine in ("jax", "reference"):
                result = score_batch(clips, engine=engine, config=SGCConfig(), progress=False)
                for table, records in (("clips", result.to_records()), ("pairs", result.pair_records())):
                    for name, value in columns(records).items():
                        kept[f"{corpus}/batch-{engine}/{table}/{name}"] = value
        for path in ("scorer", "scorer-2dev"):
            if path in paths:
                devices = jax.devices() if path == "scorer-2dev" else None
                for name, value in scorer_outputs(clips, corpus_shape(clips), devices).items():
                    kept[f"{corpus}/{path}/out/{name}"] = value
    return kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--against", help="an earlier --out: list every key whose values differ")
    parser.add_argument("--paths", nargs="+", default=("batch", "scorer", "scorer-2dev"))
    parser.add_argument("--two-devices", action="store_true", help=argparse.SUPPRESS)  # the subprocess
    args = parser.parse_args()
    if args.two_devices:
        np.savez(args.out, **collect(("scorer-2dev",)))
        return
    kept = collect(tuple(p for p in args.paths if p != "scorer-2dev"))
    if "scorer-2dev" in args.paths:
        flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
        part = args.out + ".2dev.npz"
        subprocess.run([sys.executable, __file__, "--out", part, "--two-devices"], check=True,
                       env={**os.environ, "XLA_FLAGS": flags})
        with np.load(part) as two:
            kept.update({key: two[key] for key in two.files})
        os.remove(part)
    out = args.out if args.out.endswith(".npz") else args.out + ".npz"  # np.savez adds the suffix
    np.savez(out, **kept)
    print(f"{len(kept)} columns -> {out}")
    if args.against:
        with np.load(args.against) as before:
            differ = [key for key in sorted(set(before.files) | set(kept))
                      if key not in before.files or key not in kept
                      or not np.array_equal(before[key], kept[key], equal_nan=before[key].dtype.kind == "f")]
        print(f"{len(differ)} of {len(kept)} columns differ from {args.against}" + "".join(f"\n  {k}" for k in differ))
        sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()

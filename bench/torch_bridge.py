"""The PyTorch bridge's cost over the JAX Scorer it wraps (docs/semantics.md §9.5), per call, in one run.

    python bench/torch_bridge.py [--batch-size 4] [--repeat 20] [--device cpu|cuda:0]

The demo corpus's clips (8 frames, 96x128 px, 1024 tracks; a batch of ``--batch-size`` of them,
repeated to fill it), scored by ``Scorer`` from jax.Arrays and by ``TorchScorer`` from torch tensors
on ``--device``, alternated call by call; prints each one's median wall time per call (waited for),
their ratio, and which batch tensors the bridge copied (none, for a batch in torch's own memory).
"""

from __future__ import annotations

import argparse
import statistics
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    import jax
    import torch

    from sgc_jax import Scorer, batch_of
    from sgc_jax.research.synth import demo_corpus
    from sgc_jax.torch import TorchScorer, batch_tensors, jax_device_of

    corpus = demo_corpus()
    clips = [corpus[i % len(corpus)] for i in range(args.batch_size)]
    batch = batch_of(clips)
    shape = (args.batch_size, *batch["depth"].shape[1:], batch["track_prev"].shape[2])
    bridge = TorchScorer(shape, device=args.device)
    device = jax_device_of(args.device)
    scorer = Scorer(shape, devices=[device])
    tensors = batch_tensors(batch, args.device)
    arrays = {name: jax.device_put(value, device) for name, value in bridge.arrays(tensors).items()}

    def sync() -> None:
        if torch.device(args.device).type == "cuda":
            torch.cuda.synchronize()

    times: dict[str, list[float]] = {"Scorer": [], "TorchScorer": []}
    for _ in range(args.repeat + 1):
        for name, call in (("Scorer", lambda: jax.block_until_ready(scorer(arrays))),
                           ("TorchScorer", lambda: (bridge(tensors), sync()))):
            start = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - start)
    medians = {name: statistics.median(t[1:]) * 1000 for name, t in times.items()}  # the first call warms up
    print(f"{jax.devices()[0].device_kind if args.device != 'cpu' else 'cpu'}, B = {args.batch_size}: "
          f"Scorer {medians['Scorer']:.1f} ms, TorchScorer {medians['TorchScorer']:.1f} ms per call "
          f"({medians['TorchScorer'] / medians['Scorer']:.3f}x); tensors copied: {bridge.copies or 'none'}")


if __name__ == "__main__":
    main()

"""Clips handed from reader processes to the scoring process (docs/semantics.md §4.1): a prepared
clip through the reader's pipe at Linux's default 64 KB against ``readers.PIPE_BYTES``, with the
scoring process's other threads busy in Python, as its lanes and scoring thread are on a GPU host.

    python bench/reader_transfer.py [--clips 16] [--readers 2] [--busy 1] [--dir /tmp/sgc-stream-corpus]

Writes (once) --clips standard clip files (bench/stream.py's corpus), then reads them all through
``ReaderProcesses`` each way, alternated twice, while --busy threads of the caller spin in Python.
Prints the wall time per clip and the caller's CPU time per clip in the threads that receive.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

from sgc_jax import SGCConfig
from sgc_jax.io.loading import entries_from_file
from sgc_jax.scoring import readers

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stream import write_corpus  # noqa: E402


def read_all(paths: list[Path], n_readers: int, busy: int, pipe_bytes: int) -> float:
    """Seconds per clip to read ``paths`` through reader processes (started before the clock)."""
    readers.PIPE_BYTES = pipe_bytes
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            sum(range(1000))

    spinners = [threading.Thread(target=spin) for _ in range(busy)]
    with readers.ReaderProcesses(n_readers, "jax", SGCConfig()) as processes:
        entries = [entries_from_file(path, SGCConfig())[0] for path in paths]
        for future in [processes.submit(entry) for entry in entries[:n_readers]]:  # every reader started
            future.result()
        for spinner in spinners:
            spinner.start()
        begin = time.perf_counter()
        futures = [processes.submit(entry) for entry in entries]
        for future in futures:
            future.result()
        seconds = time.perf_counter() - begin
    stop.set()
    for spinner in spinners:
        spinner.join()
    return seconds / len(paths)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--readers", type=int, default=2)
    parser.add_argument("--busy", type=int, default=1)
    parser.add_argument("--dir", default="/tmp/sgc-stream-corpus")
    args = parser.parse_args()
    paths = write_corpus(Path(args.dir), args.clips)
    enlarged = readers.PIPE_BYTES
    print(f"{args.clips} standard clips, {args.readers} reader processes, {args.busy} busy thread(s); "
          f"ms per clip, wall", flush=True)
    rows = {64 << 10: [], enlarged: []}
    for _ in range(2):
        for pipe_bytes, ms in rows.items():
            ms.append(1000 * read_all(paths, args.readers, args.busy, pipe_bytes))
    for name, ms in rows.items():
        print(f"| pipe of {name >> 10} KB | {', '.join(f'{m:.0f}' for m in ms)} (median {statistics.median(ms):.0f}) |", flush=True)


if __name__ == "__main__":
    main()

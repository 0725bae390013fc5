"""Generate the shape cache (resumable): python -m training.gen_cache --shapes 640 --workers 2
The second stream (issue 14 item 6): --kind 3 --cache training/cache_v2"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import time

from functools import partial

from .data import CACHE, CHUNK, gen_chunk, heldout_set, missing_chunks


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shapes", type=int, default=640, help="pool size target (rounded up to chunks of 16)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--heldout", type=int, default=32, help="held-out set size (0: skip)")
    ap.add_argument("--kind", type=int, default=1, help="training stream (shapes.STREAMS)")
    ap.add_argument("--cache", default=str(CACHE))
    a = ap.parse_args()
    n_chunks = -(-a.shapes // CHUNK)
    todo = missing_chunks(n_chunks, a.cache)
    t0 = time.time()
    if a.heldout:
        heldout_set(a.heldout, cache=a.cache)
    print(f"{n_chunks - len(todo)} of {n_chunks} chunks present; generating {len(todo)}", flush=True)
    done = 0
    with mp.Pool(a.workers) as pool:
        for _ in pool.imap_unordered(partial(gen_chunk, cache=a.cache, kind=a.kind), todo):
            done += 1
            dt = time.time() - t0
            print(f"chunk {done}/{len(todo)}  {done * CHUNK / dt:.2f} shapes/s", flush=True)
    print(f"done in {time.time() - t0:.0f}s", flush=True)


if __name__ == "__main__":
    main()

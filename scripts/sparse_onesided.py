#!/usr/bin/env python3
"""One-sided scans below 2,000 points: each NAME-onesided.ply of the harder set
(scripts/hard_clouds.py: what a camera on the +x+y+z diagonal sees, 3,000 points) subsampled to
500 and 1,000 points (seed 21, without replacement), written as OUT/NAME-os500.ply and
OUT/NAME-os1k.ply beside a copy of NAME.obj, so that

    target/release/nkrr eval OUT --sizes os500,os1k --methods network,nkrr

scores them. Below 2,000 points no balloon tells a one-sided scan (docs/poisson.md, "Both ways
below 2,000 points" measured the small-cloud guard on these). Not used to choose anything.

    .venv-formats/bin/python scripts/sparse_onesided.py HARD_DIR OUT
"""
import os
import shutil
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from results_clouds import write_ply  # noqa: E402

SHAPES = ["cow", "fandisk", "spot", "stanford-bunny", "suzanne", "teapot"]
SIZES = [("os500", 500), ("os1k", 1000)]
SEED = 21


def read_xyz(path):
    """The x, y, z floats of a binary little-endian PLY whose vertices are three floats (the
    harder set's clouds, as write_ply writes them)."""
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    n = int(next(line.split()[2] for line in header.splitlines() if line.startswith("element vertex")))
    return np.frombuffer(data[end:end + 12 * n], dtype="<f4").reshape(n, 3)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    hard, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    for name in SHAPES:
        shutil.copy(os.path.join(hard, f"{name}.obj"), os.path.join(out, f"{name}.obj"))
        pts = read_xyz(os.path.join(hard, f"{name}-onesided.ply"))
        rng = np.random.default_rng(SEED)
        for tag, n in SIZES:
            write_ply(os.path.join(out, f"{name}-{tag}.ply"), pts[rng.choice(len(pts), n, replace=False)])


if __name__ == "__main__":
    main()

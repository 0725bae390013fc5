#!/usr/bin/env python3
"""Clouds of other public meshes, to report on and never to choose a setting on: the meshes of
alecjacobson/common-3d-test-models (the repository the eval meshes come from) that are not in the
eval set, have a third dimension and are stored there as plain OBJ: beast, beetle (a car's body,
an open sheet), cheburashka, homer, nefertiti, ogre, rocker-arm. For each, NAME.obj and
NAME-3k.ply / NAME-10k.ply in the eval clouds' conventions (tests/data/eval/README.md: uniform
on the surface, Gaussian noise 0.005 x the longest bbox side; seeds 2 and 1), and NAME-500,
-1k and -1500.ply with the sparse clouds' seeds (scripts/results_clouds.py), so that the eval
tools score them as they score the eval set:

    git clone https://github.com/alecjacobson/common-3d-test-models ../common-3d-test-models
    .venv/bin/python scripts/other_meshes.py ../common-3d-test-models target/results/other
    target/release/nkrr eval target/results/other --sizes 3k,10k --methods network,nkrr --out target/results/other-eval
    .venv-peers/bin/python tests/peers/spsr.py --data target/results/other --sizes 3k,10k \\
        --out target/results/other/spsr --metrics-cmd "target/release/nkrr metrics"
    .venv-peers/bin/python scripts/ipsr_runs.py --ipsr ../ipsr/ipsr --data target/results/other \\
        --sizes 3k,10k --out target/results/other/ipsr

The clone stays beside the repository (each model under its owner's terms, as listed there).
"""
import os
import sys

import trimesh

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from results_clouds import SPARSE_SIZES, noisy_samples, write_ply  # noqa: E402

MESHES = ["beast", "beetle", "cheburashka", "homer", "nefertiti", "ogre", "rocker-arm"]


def main():
    repo, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    for name in MESHES:
        mesh = trimesh.load(os.path.join(repo, "data", f"{name}.obj"), process=False, force="mesh")
        mesh.export(os.path.join(out, f"{name}.obj"))
        write_ply(os.path.join(out, f"{name}-10k.ply"), noisy_samples(mesh, 10000, 1))
        write_ply(os.path.join(out, f"{name}-3k.ply"), noisy_samples(mesh, 3000, 2))
        for tag, n, seed in SPARSE_SIZES:  # 500, 1k, 1,500: the sparse clouds' seeds
            write_ply(os.path.join(out, f"{name}-{tag}.ply"), noisy_samples(mesh, n, seed))
        print("wrote", name)


if __name__ == "__main__":
    main()

"""Write a seeded shard of generated layouts (StableLego JSON files) for the
throughput benchmark (issue: batched scoring).

Usage: python benchmarks/make_shard.py [--n 500] [--out benchmarks/results/shard500] [--seed 0]
                                       [--recipe shard|small]

Recipe ``shard`` (of n): 60% voxel shapes on a 20^3 grid merged into bricks
(blob, boxes, spheres, arch, overhang, floating), 36% stairs / loaded stairs /
levers / towers, 4% large blobs (fill 0.5-0.95, 300-1000 bricks): median a
few dozen bricks, tail to about 1000. Recipe ``small`` (the small layouts
of LLM generators and robot tasks): 40% stairs / loaded stairs / towers /
levers, 45% voxel shapes on 6^3 and 8^3 grids, 15% any procedural family
(bridges, walls, cuboids, pallets, floating bricks: the tail): median about
a dozen bricks, p90 about 60. Deterministic for a seed; the folder is written atomically
(temp folder, then rename).
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.generate.procedural import random_family_layout  # noqa: E402
from stablelego_jax.generate.voxels import SHAPE_KINDS, merge_voxels, random_blob, random_voxel_shape  # noqa: E402
from stablelego_jax.formats.reader import write_layout  # noqa: E402


def shard_layouts(n: int, seed: int = 0):
    """Yield (name, Layout) for the shard (see module docstring)."""
    rng = np.random.default_rng(seed)
    n_large = max(1, round(0.04 * n))
    n_proc = round(0.36 * n)
    n_vox = n - n_large - n_proc
    fams = ("stairs", "stairs_load", "lever", "tower")
    for i in range(n):
        s = int(rng.integers(2**31))
        if i < n_vox:
            kind = SHAPE_KINDS[i % len(SHAPE_KINDS)]
            vox = random_voxel_shape(s, 20, kind)
            if not vox.any():
                vox[:2, :2, :2] = True
            yield f"vox_{kind}_{i:04d}", merge_voxels(vox, seed=s)
        elif i < n_vox + n_proc:
            fam, lay = random_family_layout(s, fams[i % len(fams)])
            yield f"{fam}_{i:04d}", lay
        else:
            fill = float(np.random.default_rng(s).uniform(0.5, 0.95))
            yield f"large_blob_{i:04d}", merge_voxels(random_blob(20, s, fill=fill), seed=s)


def small_layouts(n: int, seed: int = 0):
    """Yield (name, Layout) for the small set (see module docstring)."""
    rng = np.random.default_rng(seed)
    fams = ("stairs", "stairs_load", "tower", "lever")
    for i in range(n):
        s = int(rng.integers(2**31))
        r = i % 20
        if r < 8:
            fam, lay = random_family_layout(s, fams[i % len(fams)])
            yield f"{fam}_{i:04d}", lay
        elif r < 17:
            kind = SHAPE_KINDS[i % len(SHAPE_KINDS)]
            vox = random_voxel_shape(s, 6 if r % 2 else 8, kind)
            if not vox.any():
                vox[:2, :2, :2] = True
            yield f"vox_{kind}_{i:04d}", merge_voxels(vox, seed=s)
        else:
            fam, lay = random_family_layout(s)
            yield f"{fam.replace('/', '_')}_{i:04d}", lay


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "shard500"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--recipe", choices=["shard", "small"], default="shard")
    args = ap.parse_args()
    make = shard_layouts if args.recipe == "shard" else small_layouts
    parent = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".tmp-shard-", dir=parent)
    sizes = []
    try:
        for k, (name, lay) in enumerate(make(args.n, args.seed)):
            write_layout(lay, os.path.join(tmp, name + ".json"))
            sizes.append(lay.n)
            if (k + 1) % 50 == 0:
                print(f"{k + 1}/{args.n}", file=sys.stderr, flush=True)
        print(file=sys.stderr)
        if os.path.exists(args.out):
            shutil.rmtree(args.out)
        os.rename(tmp, args.out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    s = np.array(sizes)
    print(f"{len(s)} layouts in {args.out}: bricks median {int(np.median(s))}, "
          f"p90 {int(np.percentile(s, 90))}, max {s.max()}, total {s.sum()}")


if __name__ == "__main__":
    main()

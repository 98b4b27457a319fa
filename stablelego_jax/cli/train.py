"""``stablelego train`` and ``stablelego evaluate``: the command line of
:mod:`stablelego_jax.train` (training a layout generator with the stability
loss, and scoring it with the exact solver)."""
from __future__ import annotations

import os

__all__ = ["add_parsers", "cmd_train", "cmd_evaluate"]

from ..train import CONFIGS
from .common import int_at_least, non_negative_number, positive_seconds
from ..train.shapes import FRESH_COUNT, SPLITS


def add_parsers(sub) -> None:
    t = sub.add_parser(
        "train", help="train a brick-layout generator with shape fidelity + lambda x the stability loss",
        description="Train a generator of stablelego_jax.train (the config's net: the 3D conv net or the "
                    "layer-by-layer one) on procedural shapes and the meshes "
                    "of the config's mesh_dir (a relative path is taken from the working folder). Writes "
                    "OUT/checkpoint.npz every checkpoint_every steps and at the end, and OUT/history.json. "
                    "Needs optax: pip install 'stablelego-jax[train]'.",
    )
    t.add_argument("--config", default=os.path.join(CONFIGS, "default.json"),
                   help="JSON config (keys and defaults: stablelego_jax.train.train.DEFAULTS; "
                        "default: the packaged configs/default.json)")
    t.add_argument("--out", default=None, help="output folder (default out/train_lam<L>_seed<S>)")
    t.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.npz")
    t.add_argument("--seed", type=int, default=None, help="override the config's seed")
    t.add_argument("--lam", type=float, default=None, help="override the config's stability weight lambda")
    t.add_argument("--steps", type=int, default=None, help="override the config's step count")
    t.add_argument("--init", default=None, metavar="CHECKPOINT",
                   help="start from this checkpoint's parameters (the config's init; same net, width and "
                        "dilations), a fresh optimizer at step 0: fine-tuning, e.g. with --lam > 0")
    t.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="subsets solved at once, in threads (the config's solve_jobs; 0, the default: every core); "
                        "the same numbers whatever N")
    t.set_defaults(func=cmd_train)

    e = sub.add_parser(
        "evaluate", help="score a trained generator's decoded layouts with the exact solver",
        description="Decode the checkpoint's generator on the shapes of one split (strict and filled "
                    "decodings), score each layout with HiGHS and write one JSON line per shape and method.",
    )
    e.add_argument("--checkpoint", required=True, help="OUT/checkpoint.npz of stablelego train")
    e.add_argument("--out", required=True, help="results, one JSON object per line (written atomically)")
    e.add_argument("--heuristic", action="store_true", help="also score the merge heuristic on the same shapes")
    e.add_argument("--untrained", action="store_true",
                   help="also score the same network at initialisation (same config and seed)")
    e.add_argument("--refine", type=positive_seconds, default=None, metavar="SECONDS",
                   help="also refine each filled decoding with stablelego stabilize's re-merge rounds started from "
                        "it (exact solves, no heuristic seeds), at most SECONDS a shape: method generator_refined; with "
                        "--heuristic also the merge refined the same way (heuristic_refined)")
    e.add_argument("--refine-solves", type=int_at_least(1), default=None, metavar="N",
                   help="the refinement's budget in exact solves, alone (no time limit: the same rows on any "
                        "machine) or with --refine (whichever is spent first)")
    e.add_argument("--size-prior", type=non_negative_number, default=0.0, metavar="BETA",
                   help="decode in the order probability x (brick area in studs)^BETA, which favours long bricks "
                        "(default 0: by probability alone); rows carry size_prior when it is not 0")
    e.add_argument("--split", choices=SPLITS, default="heldout",
                   help="the config's held-out, validation or training shapes, or (fresh) procedural objects of "
                        "its recipe that none of them holds")
    e.add_argument("--fresh", type=int_at_least(1), default=None, metavar="N",
                   help=f"the number of shapes of --split fresh (default {FRESH_COUNT}; only with it)")
    e.add_argument("--layouts", default=None, metavar="DIR",
                   help="also write every layout scored as StableLego JSON (default library ids, the shape's voxel "
                        "grid) to DIR/METHOD/SHAPE.json; rows name it in 'layout'")
    e.set_defaults(func=cmd_evaluate)


def cmd_train(args) -> int:
    from ..train.train import run

    return run(args.config, args.out, args.resume, args.seed, args.lam, args.steps, args.jobs,
               widen_pool=getattr(args, "own_process", False), init=args.init)


def cmd_evaluate(args) -> int:
    import sys

    from ..train.evaluate import run

    if args.fresh is not None and args.split != "fresh":
        print(f"error: --fresh is the number of shapes of --split fresh, not of --split {args.split}",
              file=sys.stderr)
        return 2
    return run(args.checkpoint, args.out, args.split, args.heuristic, args.untrained, args.refine,
               args.refine_solves, args.size_prior, args.fresh, args.layouts)


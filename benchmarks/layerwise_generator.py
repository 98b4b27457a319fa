"""Issue 19, item 3 (a probe): a layer-by-layer generator taught the merge heuristic's covers.

    python benchmarks/layerwise_generator.py [--steps 3000] [--width 32] [--seed 0] \
        [--config-of benchmarks/results/train_full_s56/lam0_seed0/checkpoint.npz]

The library's generator (:mod:`stablelego_jax.train.net`) gives every
placement its own probability from the shape around it, all layers at once.
This probe asks whether a generator that decodes layer by layer, with the
bricks of the layer below as input, does better. Its model is 2D
convolutions per layer, mapping 13 channels to the 14 oriented brick types:
- the shape in layers z-2..z+3, held cells, parity, layer 0 and height;
- the distance of unsupported cells to held ones;
- the joints between bricks in the layer below.

It is trained with a cross-entropy against the merge's placements, taking
the layer below from the merge's cover (teacher forcing), on the training
shapes of the checkpoint's config. It prints the validation match: the
fraction of the merge's placements that get a probability above 0.5, with
the merge's layer below.

Then it decodes each validation shape bottom up, each layer with the
filled greedy decoding (:func:`stablelego_jax.train.net.decode`), feeding
the joints of the bricks just decoded to the next layer. Every cover is
judged by the exact solver (HiGHS), and so is the merge's. Prints one line
per shape (name, stands, bricks, merge stands, merge bricks) and the totals.
No stability term. ``--refine-solves N``: then each cover is refined as
``stablelego evaluate --refine-solves N`` refines a decoding. Nothing is written. Results:
BENCHMARKS.md, issue 19 item 3, session 67. The library's version (session 68):
:mod:`stablelego_jax.train.layers`, config ``net: "layers"``; this probe stays as the record of session 67.
"""
import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from scipy import ndimage

from stablelego_jax.generate.voxels import merge_voxels
from stablelego_jax.train import net
from stablelego_jax.train import train as T

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--steps", type=int, default=3000)
ap.add_argument("--width", type=int, default=32)
ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--config-of", default="benchmarks/results/train_full_s56/lam0_seed0/checkpoint.npz",
                help="the checkpoint whose config gives the shapes and their split")
ap.add_argument("--refine-solves", type=int, default=0, metavar="N",
                help="then refine each decoded cover as evaluate --refine-solves N does, and print what stands")
args = ap.parse_args()
steps, width, seed = args.steps, args.width, args.seed
cfg = T.load_checkpoint(args.config_of)[4]
tr_shapes, val, _ = T.dataset(cfg, validation=True)
K = len(net.TYPES)

def layer_features(vox, ids, z):
    """(X, Y, C) float32 features of layer z; ids: brick ids of layer z-1 decisions (-1 empty)."""
    X, Y, Z = vox.shape
    f = []
    for d in range(-2, 4):
        f.append(vox[:, :, z + d] if 0 <= z + d < Z else np.zeros((X, Y), bool))
    occ = vox[:, :, z]
    below = vox[:, :, z - 1] if z > 0 else np.ones((X, Y), bool)
    held = occ & below
    f += [held, np.full((X, Y), z % 2, bool) & occ, np.full((X, Y), z == 0) & occ]
    f.append(occ * (z + 1) / 20.0)
    if z > 0:
        b = ids[:, :, z - 1]
        jx = np.zeros((X, Y), bool); jx[:-1] = (b[:-1] >= 0) & (b[1:] >= 0) & (b[:-1] != b[1:])
        jy = np.zeros((X, Y), bool); jy[:, :-1] = (b[:, :-1] >= 0) & (b[:, 1:] >= 0) & (b[:, :-1] != b[:, 1:])
    else:
        jx = jy = np.zeros((X, Y), bool)
    f += [jx, jy]
    uns = occ & ~below
    if held.any() and uns.any():
        far = ndimage.distance_transform_cdt(~held, metric="taxicab")
        far = np.where(uns, np.minimum(far, 8), 0) / 8.0
    else:
        far = uns.astype(float)
    f.append(far)
    return np.stack(f, -1).astype(np.float32)

C = 13

def cover_ids(vox, lay):
    ids = -np.ones(vox.shape, np.int32)
    tgt = np.zeros(vox.shape + (K,), bool)
    for i, ((x, y, z), (sx, sy)) in enumerate(zip(lay.pos, lay.size)):
        ids[x:x + sx, y:y + sy, z] = i
        tgt[x, y, z, net.TYPES.index((int(sx), int(sy)))] = True
    return ids, tgt

def samples(shapes):
    arr = T.Arrays(shapes, cfg["crop"], cfg["grid"])
    xs, vs, ts = [], [], []
    for i, vox in enumerate(arr.target):
        lay = merge_voxels(vox)
        ids, tgt = cover_ids(vox, lay)
        valid = net.valid_placements(vox)
        for z in range(vox.shape[2]):
            if not vox[:, :, z].any():
                continue
            xs.append(layer_features(vox, ids, z)); vs.append(valid[:, :, z]); ts.append(tgt[:, :, z])
    return arr, np.stack(xs), np.stack(vs), np.stack(ts)

t0 = time.time()
_, trx, trv, trt = samples(tr_shapes)
vaa, vax, vav, vat = samples(val)
print("samples", trx.shape, vax.shape, round(time.time() - t0, 1), flush=True)
DIL = (1, 2, 4, 8, 1)

def init(key):
    ps, cin = [], C
    ks = jax.random.split(key, len(DIL) + 1)
    for i, _ in enumerate(DIL):
        ps.append((jax.random.normal(ks[i], (3, 3, cin, width)) * np.sqrt(2.0 / (9 * cin)), jnp.zeros(width)))
        cin = width
    ps.append((jax.random.normal(ks[-1], (cin, K)) * np.sqrt(1.0 / cin), jnp.full(K, -2.0)))
    return ps

def apply(ps, x):
    h, occ = x, x[..., 2:3]  # channel 2: the occupancy of layer z
    for (w, b), d in zip(ps[:-1], DIL):
        h = jax.lax.conv_general_dilated(h, w, (1, 1), "SAME", rhs_dilation=(d, d), dimension_numbers=("NHWC", "HWIO", "NHWC"))
        h = jax.nn.relu(h + b) * occ
    w, b = ps[-1]
    return h @ w + b

def loss(ps, x, v, t):
    lg = apply(ps, x)
    bce = jnp.where(v, optax.sigmoid_binary_cross_entropy(lg, t.astype(jnp.float32)), 0.0)
    return bce.sum((1, 2, 3)).mean()

opt = optax.adam(3e-3)
ps = init(jax.random.PRNGKey(seed)); st = opt.init(ps)
@jax.jit
def step(ps, st, x, v, t):
    l, g = jax.value_and_grad(loss)(ps, x, v, t)
    u, st = opt.update(g, st, ps)
    return optax.apply_updates(ps, u), st, l
probs = jax.jit(lambda ps, x, v: jnp.where(v, jax.nn.sigmoid(apply(ps, x)), 0.0))
rng = np.random.default_rng(seed)
t0 = time.time()
for s in range(steps):
    b = rng.choice(len(trx), 64, replace=False)
    ps, st, l = step(ps, st, trx[b], trv[b], trt[b])
    if s % 250 == 0 or s == steps - 1:
        pv = np.concatenate([np.asarray(probs(ps, vax[i:i + 256], vav[i:i + 256])) for i in range(0, len(vax), 256)])
        print(s, round(float(l), 2), "val match", round(float((pv[vat] > 0.5).mean()), 3), round(time.time() - t0, 1), flush=True)

# autoregressive decoding of the validation shapes, judged by HiGHS
def decode_shape(vox):
    ids = -np.ones(vox.shape, np.int32)
    valid = net.valid_placements(vox)
    pos, size = [], []
    for z in range(vox.shape[2]):
        if not vox[:, :, z].any():
            continue
        x = layer_features(vox, ids, z)[None]
        p = np.asarray(probs(ps, x, valid[None, :, :, z]))[0]
        idx, _, _ = net.decode(p[:, :, None, :], 0.5, True, valid[:, :, z][:, :, None, :])
        for (px, py, _, k) in idx:
            sx, sy = net.TYPES[k]
            ids[px:px + sx, py:py + sy, z] = len(pos)
            pos.append((px, py, z)); size.append((sx, sy))
    return np.array(pos), np.array(size)

res, lays = [], []
for i, name in enumerate(vaa.names):
    vox = vaa.target[i]
    pos, size = decode_shape(vox)
    lay = T.layout_of(pos + vaa.offset[i], size)
    lays.append(lay)
    ok = T.score_layout(lay)
    m = merge_voxels(vox); mok = T.score_layout(m)
    res.append((name, ok, len(pos), mok, m.n))
    print(res[-1], flush=True)
print("AR stable", sum(r[1] for r in res), "merge", sum(r[3] for r in res), "of", len(res), "bricks", sum(r[2] for r in res), sum(r[4] for r in res))
if args.refine_solves:
    import sys

    from stablelego_jax.train.evaluate import refined_rows

    t0 = time.time()
    rows = refined_rows("layerwise_refined", val, lays, None, sys.stderr, {}, args.refine_solves)
    print("refined stable", sum(r["stable"] for r in rows), "of", len(rows), round(time.time() - t0, 1), flush=True)

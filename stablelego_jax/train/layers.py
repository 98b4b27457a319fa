"""The layer-by-layer generator: 2D convolutions over each layer, the bricks of the layer below as input.

:mod:`.net`'s generator gives every placement its own probability from the
shape alone, all layers at once, so it cannot pick one tiling among equal
ones. This one sees, in each layer z, the joints between the bricks of
layer z - 1 and decodes bottom up (:func:`decode`), so each layer's bricks
can cross the joints below. In training the layer below is a teacher's
cover (the merge heuristic's, :func:`teacher`): teacher forcing.

The outputs are the same placements as :mod:`.net`'s (probabilities
(B, X, Y, Z, K) over :data:`~.net.TYPES`), so the loss, the stability
subsets and the decodings of :mod:`.train` take them as they are. Pure
functions over a params pytree (a list of (kernel, bias) pairs).

Features (X, Y, Z, :data:`N_FEATURES`) float32 per cell of layer z, all 0
outside the shape where masked: the shape in layers z-2 .. z+3 (channel 2:
layer z itself), held from below, layer parity, layer 0, height
(z + 1) / grid, the joints along x and along y between bricks of layer
z - 1, and the taxicab distance (capped at 8, / 8) of an unheld cell to the
nearest held one.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from ..layout import cells_of
from . import net

__all__ = ["N_FEATURES", "features", "brick_ids", "teacher", "init_params", "apply", "logits", "probabilities",
           "decode"]

N_FEATURES = 13
#: channel of the features holding the occupancy of the layer itself
OCCUPIED = 2
_FAR_CAP = 8


def brick_ids(shape, pos, size) -> np.ndarray:
    """(X, Y, Z) int32 grid: the index of the brick on each cell, -1 where none
    (pos (n, 3) min corners, size (n, 2) footprints in studs)."""
    ids = -np.ones(shape, np.int32)
    cells, owner = cells_of(np.asarray(pos, np.int64).reshape(-1, 3), np.asarray(size, np.int64).reshape(-1, 2))
    ids[tuple(cells.T)] = owner
    return ids


def teacher(vox: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ids (X, Y, Z) int32, placements (X, Y, Z, K) bool) of the merge
    heuristic's exact cover of ``vox`` (:func:`~stablelego_jax.generate.voxels.merge_voxels`):
    the layer below of teacher forcing and the placements to imitate."""
    from ..generate.voxels import merge_voxels

    lay = merge_voxels(vox)
    pos, size = lay.pos.astype(np.int64), lay.size.astype(np.int64)
    place = np.zeros(vox.shape + (len(net.TYPES),), bool)
    k = [net.TYPES.index((int(sx), int(sy))) for sx, sy in size]
    place[pos[:, 0], pos[:, 1], pos[:, 2], k] = True
    return brick_ids(vox.shape, pos, size), place


def features(vox: np.ndarray, ids: np.ndarray, grid: int = 20, z: int | None = None) -> np.ndarray:
    """(X, Y, Z, 13) float32 features of a bool shape ``vox`` with the bricks
    ``ids`` ((X, Y, Z) int, -1 where none; only layers below each layer are
    read); ``z``: layer z alone, (X, Y, 1, 13)."""
    vox = np.asarray(vox, bool)
    X, Y, Z = vox.shape
    zs = np.arange(Z) if z is None else np.array([z])
    pad = np.zeros((X, Y, Z + 5), bool)
    pad[:, :, 2:Z + 2] = vox
    f = [pad[:, :, zs + 2 + d] for d in range(-2, 4)]
    occ = vox[:, :, zs]
    below = np.concatenate([np.ones((X, Y, 1), bool), vox[:, :, :-1]], 2)[:, :, zs]
    held = occ & below
    f += [held, occ & (zs % 2 == 1), occ & (zs == 0), occ * (zs + 1.0) / grid]
    b = np.concatenate([-np.ones((X, Y, 1), np.int64), np.asarray(ids, np.int64)[:, :, :-1]], 2)[:, :, zs]
    jx = np.zeros(occ.shape, bool)
    jx[:-1] = (b[:-1] >= 0) & (b[1:] >= 0) & (b[:-1] != b[1:])
    jy = np.zeros(occ.shape, bool)
    jy[:, :-1] = (b[:, :-1] >= 0) & (b[:, 1:] >= 0) & (b[:, :-1] != b[:, 1:])
    f += [jx, jy]
    far = np.zeros(occ.shape)
    for i in range(len(zs)):  # host-side, once per layer
        uns = occ[:, :, i] & ~below[:, :, i]
        if not uns.any():
            continue
        if held[:, :, i].any():
            d = ndimage.distance_transform_cdt(~held[:, :, i], metric="taxicab")
            far[:, :, i] = np.where(uns, np.minimum(d, _FAR_CAP), 0) / _FAR_CAP
        else:
            far[:, :, i] = uns
    f.append(far)
    return np.stack(f, -1).astype(np.float32)


def init_params(key, width: int = 32, dilations=(1, 2, 4, 8, 1), out_bias: float = -2.0):
    """Params: 3x3 conv layers in x, y (``dilations``) of ``width`` channels,
    ReLU, then a 1x1 conv to K logits (bias ``out_bias``)."""
    params, cin = [], N_FEATURES
    keys = jax.random.split(key, len(dilations) + 1)
    for i, _ in enumerate(dilations):
        w = jax.random.normal(keys[i], (3, 3, cin, width), jnp.float32) * float(np.sqrt(2.0 / (9 * cin)))
        params.append((w, jnp.zeros((width,), jnp.float32)))
        cin = width
    w = jax.random.normal(keys[-1], (cin, len(net.TYPES)), jnp.float32) * float(np.sqrt(1.0 / cin))
    params.append((w, jnp.full((len(net.TYPES),), out_bias, jnp.float32)))
    return params


def _conv2(h, w, d: int):
    """'SAME' 3x3 convolution with dilation ``d`` of ``h`` (N, X, Y, C); ``w``
    (3, 3, C, O). XLA's convolution: in 2D it is faster on the CPU than a
    matmul over the 9 shifted copies (0.70 s against 1.07 s forward +
    backward for 160 layers of 20 x 20 at width 32)."""
    return jax.lax.conv_general_dilated(h, w, (1, 1), "SAME", rhs_dilation=(d, d),
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))


def apply(params, x, dilations=(1, 2, 4, 8, 1)):
    """Logits (B, X, Y, Z, K) of features ``x`` (B, X, Y, Z, 13), each layer on
    its own; hidden activations masked to the layer's cells (so a crop
    gives the same output as the whole grid)."""
    B, X, Y, Z, C = x.shape
    h = jnp.moveaxis(x, 3, 1).reshape(B * Z, X, Y, C)
    occ = h[..., OCCUPIED:OCCUPIED + 1]
    for (w, b), d in zip(params[:-1], dilations):
        h = jax.nn.relu(_conv2(h, w, d) + b) * occ
    w, b = params[-1]
    out = (h @ w + b).reshape(B, Z, X, Y, -1)
    return jnp.moveaxis(out, 1, 3)


def logits(params, x, dilations=(1, 2, 4, 8, 1), logit_bound: float = 0.0):
    """(B, X, Y, Z, K) float64 logits of :func:`apply` (``logit_bound``: as :func:`.net.logits`)."""
    lg = apply(params, x, dilations).astype(jnp.float64)
    return net.bound_logits(lg, logit_bound) if logit_bound > 0 else lg


def probabilities(params, x, valid, dilations=(1, 2, 4, 8, 1), logit_bound: float = 0.0):
    """(B, X, Y, Z, K) float64 placement probabilities, 0 where not ``valid``."""
    return jnp.where(valid, jax.nn.sigmoid(logits(params, x, dilations, logit_bound)), 0.0)


def decode(probs_fn, params, vox, valid, grid: int = 20, threshold: float = 0.5, fill: bool = False,
           size_prior: float = 0.0):
    """Bottom-up decoding of a batch of shapes: layer z's features take the
    bricks decoded in layer z - 1, then :func:`.net.decode` picks the
    layer's bricks (``threshold``, ``fill``, ``size_prior`` as there).

    probs_fn(params, x (S, X, Y, 1, 13), valid (S, X, Y, 1, K)) -> probabilities;
    vox (S, X, Y, Z) bool, valid (S, X, Y, Z, K). Returns per shape
    (pos (n, 3), size (n, 2)), lowest layers first."""
    vox = np.asarray(vox, bool)
    S, X, Y, Z = vox.shape
    ids = -np.ones(vox.shape, np.int32)
    out = [[(np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))] for _ in range(S)]
    n = [0] * S  # bricks decoded so far, per shape
    for z in range(Z):
        live = [s for s in range(S) if vox[s, :, :, z].any()]
        if not live:
            continue
        x = np.stack([features(vox[s], ids[s], grid, z) for s in live])
        p = np.asarray(probs_fn(params, x, valid[live, :, :, z:z + 1]))
        for j, s in enumerate(live):
            _, pos, size = net.decode(p[j], threshold, fill, valid[s, :, :, z:z + 1], size_prior)
            pos[:, 2] = z
            cells, owner = cells_of(pos, size)
            ids[s][tuple(cells.T)] = owner + n[s]
            n[s] += len(pos)
            out[s].append((pos, size))
    return [(np.concatenate([q[0] for q in o]), np.concatenate([q[1] for q in o])) for o in out]

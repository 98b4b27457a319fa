"""The generator: a small 3D conv net over the (G, G, G) target grid.

For every cell and every oriented brick type (:data:`TYPES`) it outputs the
probability that a brick of that type has its min corner in that cell
(a *placement*). Placements whose window leaves the target shape are masked
to probability 0. Pure functions over a params pytree (a list of
(kernel, bias) pairs); ``jit``/``vmap``-friendly.

Shapes: ``x`` (B, G, G, G, C) input features; probabilities (B, G, G, G, K)
with K = len(TYPES); cells are (x, y, z) stud cells, z the layer.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..layout import cells_of, table_i_bricks

__all__ = ["TYPES", "MASS", "features", "crop", "valid_placements", "init_params", "apply", "bound_logits", "logits", "probabilities",
           "coverage", "window_max", "existence_weights", "subset_shares", "spanning_placements", "decode", "decoded_iou"]

#: oriented brick types (sx studs along x, sy along y): Table I in both orientations.
TYPES = ((1, 1), (1, 2), (2, 1), (1, 4), (4, 1), (1, 6), (6, 1), (1, 8), (8, 1),
         (2, 2), (2, 4), (4, 2), (2, 6), (6, 2))
#: (K,) kg, Table I mass of each type.
MASS = table_i_bricks(TYPES)[0]
N_FEATURES = 4


def features(vox: np.ndarray, grid: int = 20) -> np.ndarray:
    """(X, Y, Z, 4) float32 input features of a bool shape, all 0 outside it:
    occupied, occupied and held from below (layer 0 or an occupied cell
    under it), on layer 0, height (z + 1) / grid."""
    vox = np.asarray(vox, bool)
    below = np.zeros_like(vox)
    below[:, :, 0] = True
    below[:, :, 1:] = vox[:, :, :-1]
    z = (np.arange(vox.shape[2]) + 1.0) / grid
    f = [vox, vox & below, vox & (np.arange(vox.shape[2]) == 0), vox * z]
    return np.stack(f, -1).astype(np.float32)


def crop(vox: np.ndarray, size) -> tuple[np.ndarray, np.ndarray]:
    """(crop of ``vox`` of ``size`` (cx, cy, cz) at the shape's min x, y corner
    and z = 0, offset (ox, oy, 0)); ValueError if the shape does not fit."""
    vox = np.asarray(vox, bool)
    xs, ys, zs = np.nonzero(vox)
    if not len(xs):
        raise ValueError("empty shape")
    o = np.array([xs.min(), ys.min(), 0])
    ext = np.array([xs.max() + 1, ys.max() + 1, zs.max() + 1]) - o
    if (ext > np.asarray(size)).any():
        raise ValueError(f"shape extent {ext.tolist()} exceeds the crop {list(size)}")
    out = np.zeros(tuple(size), bool)
    sub = vox[o[0]:o[0] + size[0], o[1]:o[1] + size[1], : size[2]]
    out[: sub.shape[0], : sub.shape[1], : sub.shape[2]] = sub
    return out, o


def _window_sums(vox: np.ndarray) -> np.ndarray:
    """(X, Y, Z, K) int: the number of occupied cells of ``vox`` in each
    placement's window (summed-area table per layer; windows past the grid: 0)."""
    X, Y, Z = vox.shape
    c = np.zeros((X + 1, Y + 1, Z), np.int64)
    c[1:, 1:] = vox.astype(np.int64).cumsum(0).cumsum(1)
    out = np.zeros((X, Y, Z, len(TYPES)), np.int64)
    for k, (sx, sy) in enumerate(TYPES):
        if sx <= X and sy <= Y:
            out[: X - sx + 1, : Y - sy + 1, :, k] = c[sx:, sy:] - c[:-sx, sy:] - c[sx:, :-sy] + c[:-sx, :-sy]
    return out


def _area() -> np.ndarray:
    return np.array([sx * sy for sx, sy in TYPES])


def valid_placements(vox: np.ndarray) -> np.ndarray:
    """(G, G, G, K) bool: placement (cell, type) lies inside the shape
    (every cell of its window occupied)."""
    return _window_sums(np.asarray(vox, bool)) == _area()


def init_params(key, width: int = 16, dilations=(1, 2, 4, 1), out_bias: float = -2.0):
    """Params: 3x3x3 conv layers (``dilations``) of ``width`` channels, ReLU,
    then a 1x1x1 conv to K logits (bias ``out_bias``)."""
    params = []
    cin = N_FEATURES
    keys = jax.random.split(key, len(dilations) + 1)
    for i, _ in enumerate(dilations):
        fan = 27 * cin
        w = jax.random.normal(keys[i], (3, 3, 3, cin, width), jnp.float32) * float(np.sqrt(2.0 / fan))
        params.append((w, jnp.zeros((width,), jnp.float32)))
        cin = width
    w = jax.random.normal(keys[-1], (1, 1, 1, cin, len(TYPES)), jnp.float32) * float(np.sqrt(1.0 / cin))
    params.append((w, jnp.full((len(TYPES),), out_bias, jnp.float32)))
    return params


def _conv3(h, w, d: int):
    """'SAME' 3x3x3 convolution with dilation ``d`` as one matmul over the 27
    shifted copies of ``h`` (B, X, Y, Z, C); ``w`` (3, 3, 3, C, O). On the CPU
    this is ~4x faster than ``lax.conv_general_dilated`` (forward + backward)."""
    B, X, Y, Z, C = h.shape
    hp = jnp.pad(h, ((0, 0), (d, d), (d, d), (d, d), (0, 0)))
    cols = [hp[:, i * d:i * d + X, j * d:j * d + Y, k * d:k * d + Z, :]
            for i in range(3) for j in range(3) for k in range(3)]
    return jnp.concatenate(cols, -1) @ w.reshape(27 * C, -1)


def apply(params, x, dilations=(1, 2, 4, 1)):
    """Logits (B, X, Y, Z, K) of features ``x`` (B, X, Y, Z, C).

    Hidden activations are masked to the shape (channel 0 of ``x``), so
    every cell outside it is exactly 0 at every layer: the output on a crop
    of the grid around the shape equals the output on the whole (G, G, G)
    grid (zero padding = the empty cells), which is how training runs it
    (a (G, G, G) pass per step is ~10x slower on the CPU)."""
    h = x
    occ = x[..., :1]
    for (w, b), d in zip(params[:-1], dilations):
        h = jax.nn.relu(_conv3(h, w, d) + b) * occ
    w, b = params[-1]
    return h @ w.reshape(w.shape[-2], w.shape[-1]) + b


def bound_logits(logits, bound: float):
    """``bound * tanh(logits / bound)``: logits kept inside (-bound, bound)
    (probabilities inside (sigmoid(-bound), sigmoid(bound)))."""
    return bound * jnp.tanh(logits / bound)


def logits(params, x, dilations=(1, 2, 4, 1), logit_bound: float = 0.0):
    """(B, X, Y, Z, K) float64 logits of :func:`apply`; ``logit_bound`` > 0:
    through :func:`bound_logits`."""
    lg = apply(params, x, dilations).astype(jnp.float64)
    return bound_logits(lg, logit_bound) if logit_bound > 0 else lg


def probabilities(params, x, valid, dilations=(1, 2, 4, 1), logit_bound: float = 0.0):
    """(B, X, Y, Z, K) float64 placement probabilities: the sigmoid of
    :func:`logits`, 0 where not valid."""
    return jnp.where(valid, jax.nn.sigmoid(logits(params, x, dilations, logit_bound)), 0.0)


def _cover_kernel() -> np.ndarray:
    """(8, 8, 1, K, 1) 0/1 kernel of :func:`coverage`: tap (i, j) of type k
    is on when the placement at offset (7 - i, 7 - j) cells back covers the
    cell (i >= 8 - sx, j >= 8 - sy)."""
    ker = np.zeros((8, 8, 1, len(TYPES), 1))
    for k, (sx, sy) in enumerate(TYPES):
        ker[8 - sx:, 8 - sy:, 0, k, 0] = 1.0
    return ker


_COVER = _cover_kernel()


def coverage(p):
    """(B, G, G, G) soft coverage: the sum of the probabilities of the
    placements covering each cell (1 = covered once, > 1 = overlaps).

    One convolution over the (B, X, Y, Z, K) probabilities (windows start
    at most 7 cells back), not a sum of the 85 shifted slices: XLA fused
    that sum into every consumer of the coverage, and the training step's
    gradient compiled 3.6x slower and ran 4x slower (BENCHMARKS.md)."""
    out = jax.lax.conv_general_dilated(p, jnp.asarray(_COVER, p.dtype), (1, 1, 1), ((7, 0), (7, 0), (0, 0)),
                                       dimension_numbers=("NHWDC", "HWDIO", "NHWDC"))
    return out[..., 0]


def window_max(cov):
    """(B, X, Y, Z, K): for each placement, the largest value of ``cov``
    (B, X, Y, Z) over the cells of its window (cells past the crop count 0)."""
    B, X, Y, Z = cov.shape
    pad = jnp.pad(cov, ((0, 0), (0, 8), (0, 8), (0, 0)))
    out = []
    for sx, sy in TYPES:
        m = pad[:, :X, :Y]
        for dx in range(sx):
            for dy in range(sy):
                m = jnp.maximum(m, pad[:, dx:dx + X, dy:dy + Y])
        out.append(m)
    return jnp.stack(out, -1)


def existence_weights(p, cov, floor: float = 1e-3):
    """(B, X, Y, Z, K) soft-layout existence weights of the placements: each
    placement's *share* of its most contested cell, ``p / max(M, floor)``
    with M the largest coverage over its cells (M >= p, so weights are in
    [0, 1]). Where the probabilities tile the shape (M = 1) this is ``p``;
    a placement that alone claims its cells with p >= ``floor`` exists
    fully. Lowering a brick's probability
    therefore does not make it vanish from the stability problem unless
    another placement takes its cells over: the stability term cannot buy
    stability by leaving cells empty, and the loss of a floating brick
    pulls up (to first order) the alternatives that overlap it, since each
    of them lowers its share."""
    M = window_max(cov)
    return p / jnp.maximum(M, floor)


def subset_shares(ps, inc, floor: float = 1e-3, power: float = 1.0):
    """(B, n) existence weights of a subset of placements: each one's share
    of its most contested cell *within the subset*, ``p / max(M, floor)``
    with M the largest over its cells of the summed probability of the
    subset's placements covering the cell.

    ps: (B, n) probabilities of the subset's placements (0 for padding);
    inc: (B, c, n) 0/1, placement j covers the subset's cell i. Where one
    placement alone holds its cells the weight is 1 whatever its
    probability; where alternatives overlap they split the cell in the
    ratio of their probabilities, so every cell of the subset keeps (about)
    its full mass and the stability term can lower its loss only by moving
    probability from one brick to another, never by leaving a cell empty.

    ``power`` < 1: the shares are those of ``ps ** power`` (tempered): an
    alternative of probability 1e-4 next to a brick of probability 1 takes
    a share of about 1e-4 ** power instead of 1e-4, so a better but
    currently losing alternative still receives a useful gradient (the
    gradient of an untempered share vanishes with the loser's p)."""
    if power != 1.0:
        ps = jnp.where(ps > 0, jnp.where(ps > 0, ps, 1.0) ** power, 0.0)
    cov = jnp.einsum("bcn,bn->bc", inc, ps)
    M = jnp.max(inc * cov[:, :, None], axis=1)
    return ps / jnp.maximum(M, floor)


def spanning_placements(vox: np.ndarray) -> np.ndarray:
    """(X, Y, Z, K) bool: valid placements whose window holds both a cell
    with support below (or on layer 0) and a cell without (bricks that can
    hold an overhang)."""
    vox = np.asarray(vox, bool)
    held = vox.copy()
    held[:, :, 1:] &= vox[:, :, :-1]
    s = _window_sums(held)
    return valid_placements(vox) & (s > 0) & (s < _area())


def decode(prob: np.ndarray, threshold: float = 0.5, fill: bool = False, valid: np.ndarray | None = None,
           size_prior: float = 0.0):
    """Greedy non-overlapping layout from one shape's (X, Y, Z, K) probabilities.

    Placements with probability >= ``threshold`` are taken highest first,
    each unless it overlaps one already taken; nothing is forced in, so
    cells no such placement covers stay empty (IoU < 1). ``fill``: then go
    on down the list through every valid placement (``valid`` (X, Y, Z, K)
    bool; when None, those of probability > 0), so the layout covers the
    shape exactly (IoU 1 by construction; the probabilities still choose
    the bricks). Pass ``valid``: a saturated network's probabilities
    underflow to exactly 0 and would leave cells empty. ``size_prior``
    (beta >= 0): the list is ordered by ``prob * area ** beta`` (area in
    studs) instead of ``prob``, which favours long bricks over many small
    ones of nearly the same probability; 0 (default) is the plain order,
    and the candidates are the same for any beta. Returns (idx (n, 4) int
    [x, y, z, type], pos (n, 3), size (n, 2)).
    """
    if not (np.isfinite(size_prior) and size_prior >= 0):
        raise ValueError(f"size_prior must be a finite number >= 0, got {size_prior}")
    prob = np.asarray(prob)
    cand = np.argwhere(prob >= threshold)
    if fill:
        cand = np.argwhere(prob > 0 if valid is None else np.asarray(valid, bool))
    key = prob[tuple(cand.T)].astype(np.float64)
    if size_prior:
        key = key * _area()[cand[:, 3]].astype(np.float64) ** size_prior
    cand = cand[np.argsort(-key, kind="stable")]
    occ = np.zeros(prob.shape[:3], bool)
    keep = []
    for x, y, z, k in cand.tolist():
        sx, sy = TYPES[k]
        if occ[x:x + sx, y:y + sy, z].any():
            continue
        occ[x:x + sx, y:y + sy, z] = True
        keep.append((x, y, z, k))
    idx = np.asarray(keep, np.int64).reshape(-1, 4)
    size = np.asarray([TYPES[k] for k in idx[:, 3]], np.int64).reshape(-1, 2)
    return idx, idx[:, :3].copy(), size


def decoded_iou(vox: np.ndarray, pos: np.ndarray, size: np.ndarray) -> float:
    """Shape IoU of decoded bricks against the target ``vox`` (bool grid)."""
    occ = np.zeros(vox.shape, bool)
    cells, _ = cells_of(np.asarray(pos, np.int64).reshape(-1, 3), np.asarray(size, np.int64).reshape(-1, 2))
    occ[tuple(cells.T)] = True
    inter = (occ & vox).sum()
    union = (occ | vox).sum()
    return float(inter / union) if union else 1.0

"""Support margin: a graded stability measure for plain blocks.

Eq. 10 scores a frictionless block 0 or 1 (in equilibrium or not: it has
no drag to grade). :func:`support_scores` grades the blocks that stand by
how far the resultant of their bottom contact forces (the centre of
pressure, CoP) lies from the edge of their support polygon, the convex
hull of every vertex of their bottom contacts (all supports together: a box
straddling two boxes has the hull of both patches).

The score is the CoP's gauge in that polygon about the polygon's vertex
mean c: the fraction of the way from c to the boundary, along the ray from
c through the CoP (0: the load acts at c; 1: on the edge, the knife edge of
tipping). It is 1 for a block out of equilibrium, so it reads like Eq. 10
(< 1: the block stands; the closer to 1, the closer to tipping over), and
for a single column of blocks it is the classic centre-of-mass test: at
every interface the CoP is the centre of mass of everything above.
"""
from __future__ import annotations

import numpy as np

from .contacts import scene_contacts
from .geometry import hull_gauge
from .model import ForceModel, Params
from .scene import BLOCK, Scene
from .score import residual, residual_bad

__all__ = ["support_scores", "LOAD_TOL"]

#: A block whose bottom contacts carry less than this (N) has no centre of pressure.
LOAD_TOL = 1e-9


def support_scores(scene: Scene, model: ForceModel, f_in, params: Params | None = None) -> np.ndarray:
    """(n,) support score of each body of ``scene`` from forces ``f_in`` ((m,)
    or (m_pad,) N) solved on ``model`` (its :func:`~stablelego_jax.model.compile_scene`
    model, padded or not): 1 where the body is out of equilibrium, else the
    gauge of its bottom centre of pressure in its support polygon (module
    doc); 0 for a block in equilibrium whose bottom carries nothing (held by
    friction at its sides); NaN for bricks (graded by Eq. 10)."""
    p = params or model.params
    n = scene.n
    f = np.zeros(model.m_pad)
    f[: len(np.asarray(f_in))] = np.asarray(f_in, np.float64)  # Analysis.forces holds the real columns only
    c = scene_contacts(scene, p.stud, p.layer / 3)
    k = len(c.push_pair)
    fp = f[model.m - k: model.m]
    owner = c.push_pair[:, 0]
    sel = c.push_bottom & (owner < n)
    sel &= scene.kind[np.minimum(owner, n - 1)] == BLOCK
    owner, fz, xy = owner[sel], fp[sel] * c.push_dir[sel, 2], c.push_point[sel, :2]
    load = np.bincount(owner, fz, minlength=n)
    cop = np.stack([np.bincount(owner, fz * xy[:, d], minlength=n) for d in (0, 1)], 1)
    cop = cop / np.where(load > LOAD_TOL, load, 1.0)[:, None]
    # the bottom vertices of each block, padded to one width
    order = np.argsort(owner, kind="stable")
    owner, xy = owner[order], xy[order]
    counts = np.bincount(owner, minlength=n)
    K = max(int(counts.max(initial=0)), 1)
    slot = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
    pts = np.zeros((n, K, 2))
    valid = np.zeros((n, K), bool)
    pts[owner, slot] = xy
    valid[owner, slot] = True
    gauge = hull_gauge(pts, valid, cop)
    bad = residual_bad(residual(model, f)[:n], p)
    out = np.where(load > LOAD_TOL, np.clip(np.nan_to_num(gauge, nan=1.0), 0.0, 1.0), 0.0)
    out = np.where(bad, 1.0, out)
    return np.where(scene.kind == BLOCK, out, np.nan)

"""Heat maps of scenes: rotated and offset bricks and blocks, coloured by score.

The picture of :mod:`~stablelego_jax.render` for bodies off the stud grid:
every body a box (bricks with their studs as small squares on top), drawn in
an orthographic view with the score colours of
:func:`~stablelego_jax.render.score_cmap`, faces painted back to front by
the depth of their centres (right for stacks, piles and pallets; a long face
beside a short one can come out in the wrong order), on a ground plate.
Written atomically.
"""
from __future__ import annotations

import os

import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from .files import atomic_write
from .geometry import rect_axes
from .render import DEFAULT_VIEW, score_cmap, view_basis
from .scene import BRICK, Scene, boxes

__all__ = ["render_scene", "scene_faces"]

# shading of faces by their normal: top, sides by how much they face the light
_LIGHT = np.array([0.35, -0.5, 0.8]) / np.linalg.norm([0.35, -0.5, 0.8])
_BG = "#dfe3ea"
_GROUND = "#c9ced6"


def scene_faces(scene: Scene):
    """The faces of every body: (verts (f, 4, 3) metres, owner (f,), normal
    (f, 3)); bricks add one small square per stud on their top face."""
    centre, size, yaw = boxes(scene)
    ax = rect_axes(yaw)  # (n, 2, 2)
    ex = np.concatenate([ax[:, 0], np.zeros((scene.n, 1))], 1)
    ey = np.concatenate([ax[:, 1], np.zeros((scene.n, 1))], 1)
    ez = np.tile([0.0, 0.0, 1.0], (scene.n, 1))
    half = size / 2
    frames = [ex, ey, ez]
    verts, owner, normal = [], [], []
    for axis in range(3):
        b, c = (axis + 1) % 3, (axis + 2) % 3
        for s in (1.0, -1.0):
            n = frames[axis] * s
            base = centre + n * half[:, axis:axis + 1]
            uv = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64)
            v = base[:, None, :] + uv[None, :, 0:1] * (frames[b] * half[:, b:b + 1])[:, None, :] \
                + uv[None, :, 1:2] * (frames[c] * half[:, c:c + 1])[:, None, :]
            verts.append(v)
            owner.append(np.arange(scene.n))
            normal.append(n)
    # studs: a square of 0.5 stud on the top face at each stud centre
    br = np.nonzero(scene.kind == BRICK)[0]
    if len(br):
        studs = scene.size[br, :2].astype(np.int64)
        area = studs[:, 0] * studs[:, 1]
        o = np.repeat(br, area)
        loc = np.arange(int(area.sum())) - np.repeat(np.cumsum(area) - area, area)
        sy = np.repeat(studs[:, 1], area)
        cell = np.stack([loc // sy, loc % sy], 1) + 0.5 - scene.size[o, :2] / 2
        stud = size[o, 0] / scene.size[o, 0]  # metres per stud
        top = centre[o] + ez[o] * half[o, 2:3] * 1.0005
        c0 = top + (cell[:, 0:1] * ex[o] + cell[:, 1:2] * ey[o]) * stud[:, None]
        uv = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) * 0.25
        v = c0[:, None, :] + (uv[None, :, 0:1] * ex[o][:, None, :] + uv[None, :, 1:2] * ey[o][:, None, :]) \
            * stud[:, None, None]
        verts.append(v)
        owner.append(o)
        normal.append(ez[o])
    return np.concatenate(verts), np.concatenate(owner), np.concatenate(normal)


def render_scene(scene: Scene, scores, path: str, title: str | None = None, view=DEFAULT_VIEW, *,
                 dpi: int = 150) -> None:
    """Write a PNG heat map of ``scene`` (scores (n,) aligned with its keys:
    0 black, towards 1 red, >= 1 white, NaN blue) to ``path``, atomically."""
    s = np.asarray(scores, np.float64)
    if s.shape != (scene.n,):
        raise ValueError(f"scores must have shape ({scene.n},) (one per body of {scene.source}), got {s.shape}")
    right, up, toward = view_basis(view)
    verts, owner, normal = scene_faces(scene)
    vis = normal @ toward > 1e-9
    verts, owner, normal = verts[vis], owner[vis], normal[vis]
    depth = verts.mean(1) @ toward
    order = np.argsort(depth, kind="stable")
    verts, owner, normal = verts[order], owner[order], normal[order]
    cmap = score_cmap()
    rgba = np.array(cmap(Normalize(0.0, 1.0, clip=False)(np.ma.masked_invalid(s))))
    rgba[np.nan_to_num(s, nan=0.0) >= 1.0] = cmap.get_over()
    col = rgba[owner].copy()
    shade = 0.62 + 0.38 * np.clip(normal @ _LIGHT, 0.0, 1.0)
    col[:, :3] *= shade[:, None]
    P = np.stack([verts @ right, verts @ up], -1)
    # ground plate: the footprint's bounds plus a margin
    centre, size, _ = boxes(scene)
    r = np.hypot(size[:, 0], size[:, 1]) / 2
    lo = (centre[:, :2] - r[:, None]).min(0)
    hi = (centre[:, :2] + r[:, None]).max(0)
    pad = 0.08 * float(max(hi - lo))
    lo, hi = lo - pad, hi + pad
    ground = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    G = np.stack([ground @ right, ground @ up], -1)
    allp = np.concatenate([P.reshape(-1, 2), G])
    plo, phi = allp.min(0), allp.max(0)
    w, h = float(phi[0] - plo[0]), float(phi[1] - plo[1])
    pw = 6.0
    ph = min(max(pw * h / max(w, 1e-12), 2.0), 7.5)
    fig = Figure(figsize=(pw + 1.2, ph + 0.8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ax.set_facecolor(_BG)
    if toward[2] > 0:
        ax.add_collection(PolyCollection([G], facecolors=_GROUND, edgecolors="#9aa1ab", linewidths=0.6, zorder=1))
    ax.add_collection(PolyCollection(P, closed=True, facecolors=col, edgecolors="#262626", linewidths=0.4, zorder=3))
    ax.set_xlim(plo[0] - 0.03 * w, phi[0] + 0.03 * w)
    ax.set_ylim(plo[1] - 0.03 * h, phi[1] + 0.03 * h)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for sp in ax.spines.values():
        sp.set_visible(False)
    fin = np.isfinite(s)
    summary = f"{scene.n} bodies"
    if fin.any():
        i = int(np.nanargmax(np.where(fin, s, -np.inf)))
        nf = int((s[fin] >= 1.0).sum())
        summary += f", max {min(float(s[i]), 1.0):.2f} at {scene.keys[i]!r}, " + \
                   ("stable" if nf == 0 else f"{nf} failing")
    ax.text(0.5, 1.005, summary, transform=ax.transAxes, ha="center", va="bottom", fontsize=8, color="#333333")
    name = os.path.basename(os.path.normpath(scene.source)) if not scene.source.startswith("<") else "scene"
    ax.set_title(title if title is not None else name, fontsize=11, pad=14)
    from matplotlib.cm import ScalarMappable

    cb = fig.colorbar(ScalarMappable(norm=Normalize(0.0, 1.0), cmap=cmap), ax=ax, shrink=0.8, extend="max",
                      extendfrac=0.08, pad=0.02, aspect=25)
    cb.set_label("stability score (white: >= 1, fails)", fontsize=8)
    cb.ax.tick_params(labelsize=7)
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi, facecolor="white"), binary=True)

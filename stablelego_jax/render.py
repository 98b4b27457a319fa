"""Stability heat maps: PNG pictures of a layout coloured by per-brick score.

The picture is the one of the StableLego paper: each brick drawn in 3D and
coloured by its stability score, black for 0 (no stress) through red (close
to failing) to white for bricks that fail (score >= 1).

Drawing uses an orthographic projection computed here and painted with an
exact back-to-front order (cells of a grid can be sorted exactly; general
polygons, as in ``mplot3d``, cannot), so hidden faces never show through and
brick outlines are occluded correctly. All faces and outlines of a layout
go into one matplotlib collection: a 1000-brick layout renders in about a
second. Only faces that touch an empty cell are drawn, and outlines are drawn
only where two bricks meet or the surface folds, so individual bricks read
clearly while the stud grid inside a brick does not clutter the picture.

Files are written atomically (temporary sibling, then ``os.replace``).
"""
from __future__ import annotations

import math
import os
from typing import Sequence

import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import LinearSegmentedColormap, Normalize, to_rgba
from matplotlib.cm import ScalarMappable
from matplotlib.figure import Figure

from .files import atomic_write
from .layout import Layout

__all__ = [
    "render_heatmap",
    "render_pair",
    "contact_sheet",
    "score_cmap",
    "DEFAULT_VIEW",
    "auto_view",
    "view_across",
    "view_basis",
]

#: Layer height over stud pitch (9.6 mm / 7.8 mm): the z scale of a picture.
Z_SCALE = 9.6 / 7.8
#: (elevation, azimuth) in degrees, the ``mplot3d`` convention, of a square
#: footprint; ``view=None`` turns the azimuth to look across the longer side.
DEFAULT_VIEW = (28.0, -45.0)

_BG = "#dfe3ea"  # axes background: light, so white (failing) bricks stand out
_PLATE = "#c9ced6"
_PLATE_GRID = "#b4bac4"
_BAD = "#4a78b5"  # NaN score (no answer): blue, outside the black-red-white scale
# Face shading by orientation: top, x-side, y-side.
_SHADE = {2: 1.0, 0: 0.80, 1: 0.66}


def score_cmap():
    """Black (0) -> red (just below 1); white above 1 (fails); NaN blue."""
    cmap = LinearSegmentedColormap.from_list(
        "stablelego",
        [(0.0, "#000000"), (0.35, "#4a0000"), (0.75, "#c00000"), (1.0, "#ff2a1a")],
    )
    return cmap.with_extremes(over="#ffffff", under="#000000", bad=_BAD)


# --------------------------------------------------------------------------
# geometry


def auto_view(layout: Layout) -> tuple[float, float]:
    """A view that looks across the longer side of the footprint."""
    ext = (layout.pos[:, :2] + layout.size).max(axis=0) - layout.pos[:, :2].min(axis=0)
    return view_across(float(ext[0]), float(ext[1]))


def view_across(ext_x: float, ext_y: float) -> tuple[float, float]:
    """(elevation, azimuth) in degrees of a view across the longer side of a
    footprint ``ext_x`` x ``ext_y`` (any one length unit)."""
    r = ext_x / (ext_x + ext_y) if ext_x + ext_y > 0 else 0.5
    return DEFAULT_VIEW[0], -10.0 - 70.0 * r


def _check_view(view, layout: Layout | None = None) -> tuple[float, float]:
    if view is None:
        return auto_view(layout) if layout is not None else DEFAULT_VIEW
    try:
        elev, azim = (float(v) for v in view)
    except (TypeError, ValueError):
        raise ValueError(f"view must be (elevation, azimuth) in degrees, got {view!r}") from None
    if not (math.isfinite(elev) and math.isfinite(azim)):
        raise ValueError(f"view must be finite, got {view!r}")
    return elev, azim


def view_basis(view):
    """Screen right, screen up and towards-viewer unit vectors (world coords)
    of a view (elevation, azimuth) in degrees."""
    e, a = (math.radians(v) for v in view)
    right = np.array([-math.sin(a), math.cos(a), 0.0])
    up = np.array([-math.sin(e) * math.cos(a), -math.sin(e) * math.sin(a), math.cos(e)])
    toward = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    return right, up, toward


def _project(pts: np.ndarray, right, up) -> np.ndarray:
    """(..., 3) cell-unit points (z in layers) -> (..., 2) screen coordinates."""
    w = pts.astype(np.float64) * np.array([1.0, 1.0, Z_SCALE])
    return np.stack([w @ right, w @ up], axis=-1)


def _check_scores(layout: Layout, scores) -> np.ndarray:
    s = np.asarray(scores, dtype=np.float64)
    if s.shape != (layout.n,):
        raise ValueError(
            f"scores must have shape ({layout.n},) (one per brick of {layout.source}), got {s.shape}"
        )
    return s


class _Scene:
    """The polygons of one layout for one view, in painting order."""

    def __init__(self, layout: Layout, scores: np.ndarray, view):
        self.layout = layout
        self.scores = scores
        self.view = view
        right, up, toward = view_basis(view)
        self.right, self.up = right, up
        occ = layout.occupancy()
        X, Y, Z = occ.shape
        occp = -np.ones((X + 2, Y + 2, Z + 2), np.int64)
        occp[1:-1, 1:-1, 1:-1] = occ
        cells = np.argwhere(occ >= 0)  # (c, 3)
        owner = occ[tuple(cells.T)].astype(np.int64)
        sgn = np.sign(np.where(np.abs(toward) < 1e-12, 0.0, toward)).astype(np.int64)
        cell_key = cells @ sgn  # exact back-to-front order for grid cells
        cell_id = np.arange(len(cells))

        cmap = score_cmap()
        norm = Normalize(0.0, 1.0, clip=False)
        base = np.array(cmap(norm(np.ma.masked_invalid(scores))))  # (n, 4) rgba per brick
        fails = np.nan_to_num(scores, nan=0.0) >= 1.0
        base[fails] = cmap.get_over()  # a score of exactly 1 fails too

        corner_uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
        verts, fcol, ecol, lwk, keys = [], [], [], [], []
        for axis in range(3):
            s = int(sgn[axis])
            if s == 0:
                continue  # faces seen edge-on
            n = np.zeros(3, np.int64)
            n[axis] = s
            cp = cells + 1  # padded index
            vis = occp[tuple((cp + n).T)] == -1
            F, o, ck, cid = cells[vis], owner[vis], cell_key[vis], cell_id[vis]
            if not len(F):
                continue
            Fp = F + 1
            b, c = (axis + 1) % 3, (axis + 2) % 3
            corners = np.repeat(F[:, None, :], 4, axis=1).astype(np.float64)
            corners[:, :, axis] += 1.0 if s > 0 else 0.0
            corners[:, :, b] += corner_uv[:, 0]
            corners[:, :, c] += corner_uv[:, 1]
            P = _project(corners, right, up)  # (m, 4, 2)
            rgba = base[o].copy()
            shade = np.where(fails[o], 1.0 - 0.45 * (1.0 - _SHADE[axis]), _SHADE[axis])
            rgba[:, :3] *= shade[:, None]  # white (failing) bricks: lighter shading
            verts.append(P)
            fcol.append(rgba)
            ecol.append(rgba)  # hairline in the face colour hides antialiasing seams
            lwk.append(np.zeros(len(F)))
            keys.append(np.stack([ck, cid, np.full(len(F), axis), np.zeros(len(F), np.int64)], 1))
            # outlines: every face edge except a flat continuation of the same brick
            lum = rgba[:, :3] @ np.array([0.299, 0.587, 0.114])
            edge_rgba = np.where(
                (lum < 0.45)[:, None],
                np.array(to_rgba("#a9a9a9")),
                np.array(to_rgba("#262626")),
            )
            tangents = [-np.eye(3, dtype=np.int64)[c], np.eye(3, dtype=np.int64)[b],
                        np.eye(3, dtype=np.int64)[c], -np.eye(3, dtype=np.int64)[b]]
            for e, t in enumerate(tangents):
                same = occp[tuple((Fp + t).T)] == o
                flat = occp[tuple((Fp + t + n).T)] == -1
                draw = ~(same & flat)
                if not draw.any():
                    continue
                p0, p1 = P[draw, e], P[draw, (e + 1) % 4]
                verts.append(np.stack([p0, p1, p1, p0], axis=1))
                fcol.append(np.zeros((int(draw.sum()), 4)))
                ecol.append(edge_rgba[draw])
                lwk.append(np.ones(int(draw.sum())))
                k = int(draw.sum())
                keys.append(np.stack([ck[draw], cid[draw], np.full(k, axis), np.full(k, 1 + e)], 1))
        verts = np.concatenate(verts)
        keys = np.concatenate(keys)
        order = np.lexsort(keys.T[::-1])
        self.verts = verts[order]
        self.fcol = np.concatenate(fcol)[order]
        self.ecol = np.concatenate(ecol)[order]
        self.is_edge = np.concatenate(lwk)[order] > 0

        # baseplate: the footprint's bounding box plus one stud
        lo = layout.pos[:, :2].min(axis=0) - 1
        hi = (layout.pos[:, :2] + layout.size).max(axis=0) + 1
        self.plate_lo, self.plate_hi = lo, hi
        self.show_plate = toward[2] > 0
        pc = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
        self.plate = _project(pc, right, up)
        self.toward = toward
        allp = np.concatenate([self.verts.reshape(-1, 2), self.plate if self.show_plate else self.verts[:1, 0]])
        self.bbox = (allp.min(axis=0), allp.max(axis=0))

    def extent(self):
        lo, hi = self.bbox
        return float(hi[0] - lo[0]), float(hi[1] - lo[1])


def _summary(layout: Layout, scores: np.ndarray) -> str:
    n = layout.n
    finite = np.isfinite(scores)
    parts = [f"{n} brick{'s' if n != 1 else ''}"]
    if finite.any():
        i = int(np.nanargmax(np.where(finite, scores, -np.inf)))
        top = float(scores[i])
        if top < 1.0:  # never print a non-failing maximum as "1.00"
            top = math.floor(top * 100.0) / 100.0
        parts.append(f"max {top:.2f} at {layout.keys[i]!r}")
        nf = int((scores[finite] >= 1.0).sum())
        parts.append("stable" if nf == 0 and finite.all() else f"{nf} failing")
    if (~finite).any():
        parts.append(f"{int((~finite).sum())} without score")
    return ", ".join(parts)


def _draw(ax, scene: _Scene, panel_w_in: float, bbox=None, subtitle: str | None = None) -> None:
    """Paint ``scene`` into ``ax`` (a 2D axes); ``bbox`` overrides the framing."""
    lo, hi = bbox if bbox is not None else scene.bbox
    w = max(hi[0] - lo[0], 1.0)
    cell_pts = panel_w_in * 72.0 / w  # points per stud on screen
    lw = float(np.clip(0.085 * cell_pts, 0.15, 1.1))

    ax.set_facecolor(_BG)
    if scene.show_plate:
        ax.add_patch(_polygon(scene.plate, _PLATE, zorder=1))
        _plate_grid(ax, scene, lw, cell_pts)
    lws = np.where(scene.is_edge, lw, min(0.35, lw))
    coll = PolyCollection(
        scene.verts,
        closed=True,
        facecolors=scene.fcol,
        edgecolors=scene.ecol,
        linewidths=lws,
        joinstyle="round",
        capstyle="round",
        zorder=3,
    )
    ax.add_collection(coll)
    pad_x, pad_y = 0.04 * w + 1.0, 0.04 * max(hi[1] - lo[1], 1.0) + 1.0
    ax.set_xlim(lo[0] - pad_x, hi[0] + pad_x)
    ax.set_ylim(lo[1] - pad_y, hi[1] + pad_y)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for sp in ax.spines.values():
        sp.set_visible(False)
    if subtitle:
        ax.text(0.5, 1.005, subtitle, transform=ax.transAxes, ha="center", va="bottom",
                fontsize=8, color="#333333")


def _polygon(pts, color, zorder):
    from matplotlib.patches import Polygon

    return Polygon(pts, closed=True, facecolor=color, edgecolor="#9aa1ab", linewidth=0.6, zorder=zorder)


def _nice_step(min_step: float) -> int:
    """Smallest of 1, 2, 5, 10, 20, 50, ... that is >= ``min_step``."""
    mag = 1
    while True:
        for m in (1, 2, 5):
            if m * mag >= min_step:
                return m * mag
        mag *= 10


def _plate_grid(ax, scene: _Scene, lw: float, cell_pts: float) -> None:
    """Stud grid on the baseplate, and x / y coordinates along its front edges."""
    (x0, y0), (x1, y1) = scene.plate_lo, scene.plate_hi
    right, up, tv = scene.right, scene.up, scene.toward
    segs = []
    if cell_pts >= 3.0:  # a grid finer than 3 pt per stud is noise
        for x in range(int(x0) + 1, int(x1)):
            segs.append([[x, y0, 0], [x, y1, 0]])
        for y in range(int(y0) + 1, int(y1)):
            segs.append([[x0, y, 0], [x1, y, 0]])
    if segs:
        P = _project(np.array(segs, np.float64), right, up)
        ax.add_collection(LineCollection(P, colors=_PLATE_GRID, linewidths=0.5 * lw, zorder=2))
    fs = 6.5
    # x along the y edge nearest the viewer, y along the nearest x edge;
    # labels are offset in screen points so that foreshortening cannot pile them up
    edges = (
        (0, "x", (x0, x1), np.array([0.0, -1.0 if tv[1] < 0 else 1.0, 0.0]), y0 if tv[1] < 0 else y1),
        (1, "y", (y0, y1), np.array([1.0 if tv[0] > 0 else -1.0, 0.0, 0.0]), x1 if tv[0] > 0 else x0),
    )
    for axis, name, (lo, hi), outward, at in edges:
        d = _project(outward, right, up)
        nd = float(np.hypot(*d))
        d = d / nd if nd > 0.15 else np.array([0.0, -1.0])  # edge-on: put labels below
        step_pts = float(np.hypot(*_project(np.eye(3)[axis], right, up))) * cell_pts
        if step_pts <= 0:
            continue
        step = _nice_step(14.0 / step_pts)  # at least 14 pt between labels
        first, last = int(lo) + 1, int(hi) - 1  # the footprint's first and last cell
        ticks = [v for v in range(first, last + 1) if v % step == 0] or [first]

        def at_cell(v, along=0.5):
            q = np.zeros(3)
            q[axis] = v + along
            q[1 - axis] = at
            return _project(q, right, up)

        for v in ticks:
            p = at_cell(v)
            ax.annotate(str(v), p, xytext=tuple(8.0 * d), textcoords="offset points",
                        fontsize=fs, ha="center", va="center", color="#555555", zorder=2,
                        annotation_clip=False)
        p = at_cell((lo + hi) / 2.0, 0.0)
        ax.annotate(name, p, xytext=tuple(19.0 * d), textcoords="offset points",
                    fontsize=fs + 1.5, ha="center", va="center", color="#333333", style="italic",
                    annotation_clip=False)


def _colorbar(fig, axes, shrink=0.8, location="right", aspect=25):
    sm = ScalarMappable(norm=Normalize(0.0, 1.0), cmap=score_cmap())
    cb = fig.colorbar(sm, ax=axes, shrink=shrink, extend="max", extendfrac=0.08, pad=0.02,
                      aspect=aspect, location=location)
    cb.set_label("stability score (white: >= 1, fails)", fontsize=8)
    cb.ax.tick_params(labelsize=7)
    cb.outline.set_edgecolor("#777777")
    return cb


# --------------------------------------------------------------------------
# writing


def _save(fig: Figure, path: str, dpi: int) -> None:
    """Save as PNG atomically: never half-written."""
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi, facecolor="white"), binary=True)


def _panel_size(extent, width_in: float, max_h_in: float, min_in: float = 2.0):
    w, h = extent
    w, h = max(w, 1.0), max(h, 1.0)
    pw = width_in
    ph = pw * h / w
    if ph > max_h_in:
        ph = max_h_in
        pw = max(min_in, ph * w / h)
    return pw, max(ph, min_in)


def _default_title(layout: Layout) -> str:
    if layout.source and not layout.source.startswith("<"):
        return os.path.basename(os.path.normpath(layout.source))
    return "layout"


# --------------------------------------------------------------------------
# public API


def render_heatmap(
    layout: Layout,
    scores,
    path: str,
    title: str | None = None,
    view=None,
    *,
    dpi: int = 150,
) -> None:
    """Write a PNG stability heat map of ``layout``.

    Args:
      layout: the bricks.
      scores: (n,) per-brick scores aligned with ``layout.keys``; 0 is drawn
        black, values towards 1 red, >= 1 (failing) white, NaN blue.
      path: PNG file to write (atomically).
      title: figure title; default the layout's file name.
      view: (elevation, azimuth) in degrees (``mplot3d`` convention); default
        ``DEFAULT_VIEW``.
      dpi: resolution.
    """
    view = _check_view(view, layout)
    s = _check_scores(layout, scores)
    scene = _Scene(layout, s, view)
    pw, ph = _panel_size(scene.extent(), 6.0, 7.5, min_in=1.5)
    fig = Figure(figsize=(pw + 1.2, ph + 0.8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    _draw(ax, scene, pw, subtitle=_summary(layout, s))
    ax.set_title(title if title is not None else _default_title(layout), fontsize=11, pad=14)
    _colorbar(fig, ax)
    _save(fig, path, dpi)


def render_pair(
    before_layout: Layout,
    before_scores,
    after_layout: Layout,
    after_scores,
    path: str,
    *,
    titles: tuple[str, str] = ("before", "after"),
    title: str | None = None,
    view=None,
    dpi: int = 150,
) -> None:
    """Side-by-side heat maps (e.g. a layout before and after repair).

    Both panels use the same view, colour scale and framing, so bricks that
    did not move are drawn in the same place.
    """
    view = _check_view(view, after_layout)
    sb = _check_scores(before_layout, before_scores)
    sa = _check_scores(after_layout, after_scores)
    scenes = [_Scene(before_layout, sb, view), _Scene(after_layout, sa, view)]
    lo = np.minimum(scenes[0].bbox[0], scenes[1].bbox[0])
    hi = np.maximum(scenes[0].bbox[1], scenes[1].bbox[1])
    ext = (hi[0] - lo[0], hi[1] - lo[1])
    if ext[0] > 2.2 * ext[1]:  # wide drawings: one above the other
        pw, ph = _panel_size(ext, 8.0, 4.0, min_in=1.3)
        fig = Figure(figsize=(pw + 1.3, 2 * ph + 1.3 + (0.3 if title else 0.0)), layout="constrained")
        axes = fig.subplots(2, 1)
    else:
        pw, ph = _panel_size(ext, 4.6, 6.5)
        fig = Figure(figsize=(2 * pw + 1.3, ph + 1.0 + (0.3 if title else 0.0)), layout="constrained")
        axes = fig.subplots(1, 2)
    for ax, sc, t, lay, s in zip(axes, scenes, titles, (before_layout, after_layout), (sb, sa)):
        _draw(ax, sc, pw, bbox=(lo, hi), subtitle=_summary(lay, s))
        ax.set_title(t, fontsize=11, pad=14)
    if title:
        fig.suptitle(title, fontsize=12)
    _colorbar(fig, list(axes), shrink=0.75)
    _save(fig, path, dpi)


def contact_sheet(
    items: Sequence[tuple[str, Layout, object]],
    path: str,
    cols: int = 4,
    *,
    view=None,
    dpi: int = 120,
    panel_in: float = 3.2,
) -> None:
    """A grid of heat maps, one per ``(title, layout, scores)`` item."""
    items = list(items)
    if not items:
        raise ValueError("contact_sheet needs at least one (title, layout, scores) item")
    if int(cols) < 1:
        raise ValueError(f"cols must be >= 1, got {cols!r}")
    fixed = _check_view(view) if view is not None else None
    scenes, summaries = [], []
    for title, lay, sc in items:
        s = _check_scores(lay, sc)
        scenes.append(_Scene(lay, s, fixed or auto_view(lay)))
        summaries.append(_summary(lay, s))
    cols = min(int(cols), len(items))
    rows = -(-len(items) // cols)
    # each row as tall as its tallest panel needs (h / w of the drawing, capped)
    ratios = [min(max(sc.extent()[1] / max(sc.extent()[0], 1.0), 0.3), 1.6) for sc in scenes]
    row_h = [panel_in * max(ratios[r * cols:(r + 1) * cols]) for r in range(rows)]
    fig = Figure(figsize=(cols * panel_in + 0.4, sum(row_h) + 0.55 * rows + 0.9), layout="constrained")
    gs = fig.add_gridspec(rows, cols, height_ratios=[h + 0.55 for h in row_h])
    axes = [fig.add_subplot(gs[i // cols, i % cols]) for i in range(rows * cols)]
    for ax, (title, lay, _), sc, summ in zip(axes, items, scenes, summaries):
        _draw(ax, sc, panel_in, subtitle=summ)
        ax.set_title(str(title), fontsize=9, pad=11)
    for ax in axes[len(items):]:
        ax.set_visible(False)
    _colorbar(fig, axes, shrink=min(0.6, 2.5 / cols), location="bottom", aspect=35)
    _save(fig, path, dpi)

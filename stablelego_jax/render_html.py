"""Interactive 3D heat maps: one self-contained HTML page per layout or sequence.

The page draws every brick (or body of a scene: plates, turned bricks,
plain blocks) as a box coloured by its stability score (the
colour scale of :mod:`~stablelego_jax.render`: black 0, red towards 1,
white failing), with plotly.js (bundled by the ``plotly`` package and
written into the page, so it opens offline): drag to turn, scroll to zoom,
hover a brick for its key, size, cell and score. A page of several frames
(the steps of a build sequence) has a step slider and buttons; the view is
kept while stepping.

Boxes are in stud units (7.8 mm), layers ``9.6 / 7.8`` studs high, as in
the PNG; a scene's bodies are drawn at their positions and yaws in the
same units (:func:`box_corners`).
Files are written atomically. Needs the ``html`` extra
(``pip install 'stablelego-jax[html]'``).
"""
from __future__ import annotations

import html
import json
import math
import os
import shutil
import subprocess
import tempfile
from typing import Sequence

import numpy as np

from .files import atomic_write, atomic_write_text
from .geometry import rect_corners
from .layout import Layout
from .render import Z_SCALE, score_cmap, view_across
from .scene import BRICK, STUD_M, Scene, body_word, boxes

__all__ = ["Frame", "html_heatmap", "html_frames", "score_colors", "box_corners", "find_chromium", "screenshot"]


class Frame:
    """One picture of a page: ``layout`` (a Layout or a Scene), its (n,)
    ``scores`` (NaN: no score), a ``label`` for the slider and a one-line
    ``note``; ``extra`` (k,) bool marks bricks drawn grey (loads, supports)."""

    def __init__(self, layout: Layout | Scene, scores, label: str = "", note: str = "", extra=None):
        self.layout = layout
        self.scores = np.asarray(scores, np.float64).reshape(layout.n)
        self.label = label
        self.note = note
        self.extra = np.zeros(layout.n, bool) if extra is None else np.asarray(extra, bool).reshape(layout.n)


def score_colors(scores) -> list:
    """``#rrggbb`` of each score on the heat-map scale (>= 1 white, NaN blue)."""
    cmap = score_cmap()
    s = np.asarray(scores, np.float64)
    rgba = np.array(cmap(np.ma.masked_invalid(np.clip(s, 0.0, 0.999999))))
    rgba[np.nan_to_num(s, nan=0.0) >= 1.0] = cmap.get_over()
    return ["#%02x%02x%02x" % tuple(int(round(255 * c)) for c in row[:3]) for row in rgba.reshape(-1, 4)]


def box_corners(layout: Layout | Scene) -> np.ndarray:
    """(n, 8, 3) corners of every body's box in drawing units (studs; a
    layer is ``Z_SCALE`` high): the bottom face counter-clockwise from the
    body's own (-x, -y) corner, then the top face in the same order."""
    if isinstance(layout, Scene):
        centre, size, yaw = (v / STUD_M if i < 2 else v for i, v in enumerate(boxes(layout)))
        xy = rect_corners(centre[:, :2], size[:, :2], yaw)  # (n, 4, 2)
        z0, z1 = centre[:, 2] - size[:, 2] / 2, centre[:, 2] + size[:, 2] / 2
    else:
        lo, sz = layout.pos[:, :2].astype(np.float64), layout.size.astype(np.float64)
        xy = rect_corners(lo + sz / 2, sz, np.zeros(layout.n))
        z0 = layout.pos[:, 2] * Z_SCALE
        z1 = z0 + Z_SCALE
    zz = np.stack([np.repeat(z0[:, None], 4, 1), np.repeat(z1[:, None], 4, 1)], 1)  # (n, 2, 4)
    return np.concatenate([np.tile(xy, (1, 2, 1)), zz.reshape(-1, 8, 1)], axis=2)


def _describe(lay: Layout | Scene, i: int) -> str:
    """How a hover names body ``i``: key, size and place in the layout's own units."""
    k = lay.keys[i]
    if not isinstance(lay, Scene):
        (x, y, z), (sx, sy) = lay.pos[i].tolist(), lay.size[i].tolist()
        return f"brick {k!r} {int(sx)}x{int(sy)} at ({int(x)},{int(y)},{int(z)})"
    (x, y, z), (sx, sy, sz), yaw = lay.pos[i].tolist(), lay.size[i].tolist(), float(lay.yaw[i])
    turn = f", yaw {yaw:g} deg" if yaw % 360 else ""
    if lay.kind[i] == BRICK:
        part = "plate" if sz == 1 else "brick" if sz == 3 else f"part {sz:g} plates high"
        return f"{part} {k!r} {int(sx)}x{int(sy)} at ({x:g},{y:g}) studs, level {z:g}{turn}"
    return (f"{body_word(lay.kind[i])} {k!r} {sx * 1e3:.4g}x{sy * 1e3:.4g}x{sz * 1e3:.4g} mm "
            f"at ({x * 1e3:.4g},{y * 1e3:.4g},{z * 1e3:.4g}) mm{turn}")


def _frame_json(fr: Frame) -> dict:
    lay = fr.layout
    s = fr.scores
    text = [_describe(lay, i) + ": " + ("no score" if not math.isfinite(v) else
                                         f"score {v:.3f}" + (" FAILS" if v >= 1.0 else ""))
            for i, v in enumerate(s.tolist())]
    cols = score_colors(s)
    cols = ["#9aa1ab" if e else c for c, e in zip(cols, fr.extra.tolist())]
    corners = np.round(box_corners(lay), 4)
    return {"label": fr.label, "note": fr.note, "corners": corners.tolist(), "color": cols, "text": text}


# The page: plotly.js, the frames as JSON, and a small script that turns a
# frame into a mesh of boxes (12 triangles each) and their outlines.
_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:0;background:#fff}}#head{{padding:8px 14px}}
#plot{{width:100%}}#note{{color:#333;font-size:14px}}
#ctl{{display:{ctl_display};align-items:center;gap:8px;margin-top:6px}}#step{{flex:1;max-width:640px}}</style>
<script>{plotly}</script></head>
<body><div id="head"><b>{title}</b> <span id="note"></span>
<div id="ctl"><button id="prev">&#9664;</button><input type="range" id="step" min="0" max="{last}" value="{last}">
<button id="next">&#9654;</button><span id="lab"></span></div></div>
<div id="plot"></div>
<script>
const FRAMES = {frames};
const SCALE = {colorscale};
function box(f) {{
  const x = [], y = [], z = [], i = [], j = [], k = [], fc = [], tx = [];
  const ex = [], ey = [], ez = [];
  const T = [[0,1,2],[0,2,3],[4,6,5],[4,7,6],[0,4,5],[0,5,1],[1,5,6],[1,6,2],[2,6,7],[2,7,3],[3,7,4],[3,4,0]];
  const E = [[0,1],[1,2],[2,3],[3,0],[4,5],[5,6],[6,7],[7,4],[0,4],[1,5],[2,6],[3,7]];
  f.corners.forEach((V, b) => {{
    const v0 = x.length;
    V.forEach(q => {{ x.push(q[0]); y.push(q[1]); z.push(q[2]); tx.push(f.text[b]); }});
    T.forEach(t => {{ i.push(v0 + t[0]); j.push(v0 + t[1]); k.push(v0 + t[2]); fc.push(f.color[b]); }});
    E.forEach(e => {{ for (const q of [V[e[0]], V[e[1]]]) {{ ex.push(q[0]); ey.push(q[1]); ez.push(q[2]); }}
                      ex.push(null); ey.push(null); ez.push(null); }});
  }});
  return [
    {{type: "mesh3d", x, y, z, i, j, k, facecolor: fc, flatshading: true, text: tx, hoverinfo: "text",
      lighting: {{ambient: 0.75, diffuse: 0.5, specular: 0.05}}, name: "bricks"}},
    {{type: "scatter3d", mode: "lines", x: ex, y: ey, z: ez, hoverinfo: "skip", showlegend: false,
      line: {{color: "#555", width: 2}}}},
    {{type: "scatter3d", mode: "markers", x: [x[0]], y: [y[0]], z: [z[0]], hoverinfo: "skip", showlegend: false,
      marker: {{size: 0.1, opacity: 0, color: [0], cmin: 0, cmax: 1, colorscale: SCALE, showscale: true,
               colorbar: {{title: {{text: "score (white: fails)"}}, len: 0.6}}}}}}];
}}
const AX = {{showbackground: true, backgroundcolor: "#dfe3ea", gridcolor: "#fff"}};
const LAYOUT = {{margin: {{l: 0, r: 0, t: 0, b: 0}}, uirevision: "keep", showlegend: false,
  width: window.innerWidth, height: Math.max(300, window.innerHeight - {head_px}),
  scene: {{aspectmode: "data", xaxis: {{...AX, title: {{text: "x (studs)"}}}}, yaxis: {{...AX, title: {{text: "y (studs)"}}}},
          zaxis: {{...AX, title: {{text: "z"}}, showticklabels: false}},
          camera: {{eye: {eye}}}}}}};
function show(n) {{
  const f = FRAMES[n];
  document.getElementById("note").textContent = f.note;
  document.getElementById("lab").textContent = f.label;
  Plotly.react("plot", box(f), LAYOUT, {{displaylogo: false, responsive: true}});
}}
const st = document.getElementById("step");
st.addEventListener("input", () => show(+st.value));
document.getElementById("prev").onclick = () => {{ st.value = Math.max(0, +st.value - 1); show(+st.value); }};
document.getElementById("next").onclick = () => {{ st.value = Math.min(FRAMES.length - 1, +st.value + 1); show(+st.value); }};
show(+st.value);
</script></body></html>
"""


def _colorscale() -> list:
    v = np.linspace(0.0, 0.999, 11)
    return [[float(t), c] for t, c in zip(v / v[-1], score_colors(v))]


def html_frames(frames: Sequence[Frame], path: str, title: str = "stablelego") -> None:
    """Write a page of ``frames`` (one: a heat map; several: a step slider,
    opening on the last) to ``path`` atomically."""
    frames = list(frames)
    if not frames:
        raise ValueError("html_frames needs at least one frame")
    try:
        from plotly.offline import get_plotlyjs
    except ImportError:
        raise RuntimeError("--html needs plotly: pip install 'stablelego-jax[html]'") from None
    data = json.dumps([_frame_json(f) for f in frames], separators=(",", ":")).replace("</", "<\\/")
    ext = np.ptp(box_corners(frames[-1].layout).reshape(-1, 3)[:, :2], axis=0)
    elev, azim = (math.radians(v) for v in view_across(float(ext[0]), float(ext[1])))  # the PNG's view
    eye = {"x": 3.4 * math.cos(elev) * math.cos(azim), "y": 3.4 * math.cos(elev) * math.sin(azim),
           "z": 3.4 * math.sin(elev)}
    page = _PAGE.format(title=html.escape(title), plotly=get_plotlyjs(), frames=data,
                        colorscale=json.dumps(_colorscale()), last=len(frames) - 1, eye=json.dumps(eye),
                        ctl_display="flex" if len(frames) > 1 else "none", head_px=80 if len(frames) > 1 else 40)
    atomic_write_text(path, page)


def html_heatmap(layout: Layout | Scene, scores, path: str, title: str | None = None, note: str = "") -> None:
    """Write the 3D heat map page of one layout; ``scores`` (n,) as for
    :func:`~stablelego_jax.render.render_heatmap`."""
    html_frames([Frame(layout, scores, note=note)], path, title or layout.source)


def find_chromium() -> str | None:
    """Path of a Chromium (or Chrome) binary on PATH, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


def screenshot(page: str, png: str, size: tuple[int, int] = (1000, 750), wait_ms: int = 8000,
               timeout_s: float = 120.0) -> None:
    """Open ``page`` in headless Chromium (a new empty profile, no network
    services, software WebGL) in a ``size`` (width, height) pixel window and
    write a PNG of it to ``png`` (the blank band below the page's viewport,
    which headless Chromium leaves for its absent window frame, cut off).
    RuntimeError when Chromium is missing or fails."""
    exe = find_chromium()
    if exe is None:
        raise RuntimeError("screenshot needs Chromium (Debian: apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="stablelego-chromium-") as profile:
        tmp = os.path.join(profile, "shot.png")
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars",
               f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
               f"--virtual-time-budget={int(wait_ms)}", f"--screenshot={tmp}",
               "file://" + os.path.abspath(page)]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"{page}: Chromium did not finish in {timeout_s:g} s") from None
        if r.returncode != 0 or not os.path.exists(tmp):
            raise RuntimeError(f"{page}: Chromium failed ({r.returncode}): {r.stderr.strip()[-300:]}")
        from matplotlib.image import imread, imsave

        img = imread(tmp)
    filled = np.nonzero((img[..., :3] < 0.99).any(axis=(1, 2)))[0]
    img = img[: filled[-1] + 1] if filled.size else img
    atomic_write(png, lambda fh: imsave(fh, img, format="png"), binary=True)

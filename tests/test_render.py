"""Heat-map rendering: valid PNGs, atomic writes, argument checks."""
import os

import numpy as np
import pytest

from stablelego_jax.formats.reader import load_layout
from stablelego_jax.formats.stablelego import parse_text_layout
from stablelego_jax.layout import make_layout
from stablelego_jax.render import contact_sheet, render_heatmap, render_pair

from conftest import SHARED_REF as REF, needs_shared  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_size(path):
    """(width, height) from the IHDR chunk; asserts the file is a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == PNG_MAGIC, f"{path} is not a PNG"
    assert head[12:16] == b"IHDR"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def _check_png(path):
    assert os.path.isfile(path)
    assert os.path.getsize(path) > 1000
    w, h = _png_size(path)
    assert w > 100 and h > 100
    import matplotlib.image as mpimg

    img = mpimg.imread(path)  # decodes the whole file: catches truncation
    assert img.shape[:2] == (h, w)
    return img


def _small():
    return parse_text_layout("2x4 (0,0,0)\n2x2 (1,0,1)\n1x4 (0,3,1)\n1x1 (2,2,2)\n", source="small.txt")


def _leftovers(d):
    return [f for f in os.listdir(d) if f.startswith(".tmp-")]


def test_render_heatmap(tmp_path):
    lay = _small()
    p = str(tmp_path / "h.png")
    render_heatmap(lay, [0.0, 0.4, 0.9, 1.2], p, title="small")
    img = _check_png(p)
    # the failing brick is drawn white-ish, the others dark or red: several colours appear
    assert len(np.unique((img[..., :3] * 8).astype(int).reshape(-1, 3), axis=0)) > 10
    assert _leftovers(tmp_path) == []


def test_render_heatmap_options(tmp_path):
    lay = _small()
    scores = np.array([0.1, np.nan, 1.0, 0.5])  # NaN: no answer; exactly 1 fails
    for i, view in enumerate([None, (30, -60), (90, 0), (0, -90), (-20, 30)]):
        p = str(tmp_path / f"v{i}.png")
        render_heatmap(lay, scores, p, view=view)
        _check_png(p)


def test_render_accepts_jax_arrays(tmp_path):
    jnp = pytest.importorskip("jax.numpy")
    lay = _small()
    p = str(tmp_path / "j.png")
    render_heatmap(lay, jnp.linspace(0.0, 1.0, lay.n), p)
    _check_png(p)


def test_render_overwrites(tmp_path):
    lay = _small()
    p = str(tmp_path / "h.png")
    render_heatmap(lay, np.zeros(lay.n), p)
    render_heatmap(lay, np.ones(lay.n), p)
    _check_png(p)
    assert os.listdir(tmp_path) == ["h.png"]


@pytest.mark.parametrize("scores", [np.zeros(3), np.zeros(5), np.zeros((4, 1)), np.zeros(0)])
def test_render_rejects_misaligned_scores(tmp_path, scores):
    p = str(tmp_path / "bad.png")
    with pytest.raises(ValueError, match="scores"):
        render_heatmap(_small(), scores, p)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("view", [(1, 2, 3), "top", (np.nan, 0)])
def test_render_rejects_bad_view(tmp_path, view):
    with pytest.raises(ValueError, match="view"):
        render_heatmap(_small(), np.zeros(4), str(tmp_path / "bad.png"), view=view)
    assert os.listdir(tmp_path) == []


def test_failed_save_leaves_no_file(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    def boom(self, *a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", boom)
    p = str(tmp_path / "h.png")
    with pytest.raises(RuntimeError):
        render_heatmap(_small(), np.zeros(4), p)
    assert os.listdir(tmp_path) == []


def test_failed_save_keeps_old_file(tmp_path, monkeypatch):
    p = str(tmp_path / "h.png")
    render_heatmap(_small(), np.zeros(4), p)
    before = open(p, "rb").read()
    from matplotlib.figure import Figure

    real = Figure.savefig

    def half(self, fh, *a, **k):
        real(self, fh, *a, **k)
        fh.truncate(100)  # a half-written PNG ...
        raise RuntimeError("interrupted")  # ... then the failure

    monkeypatch.setattr(Figure, "savefig", half)
    with pytest.raises(RuntimeError):
        render_heatmap(_small(), np.ones(4), p)
    assert open(p, "rb").read() == before
    assert os.listdir(tmp_path) == ["h.png"]


def test_render_pair(tmp_path):
    before = _small()
    after = parse_text_layout("2x4 (0,0,0)\n2x2 (1,0,1)\n1x4 (0,3,1)\n1x1 (2,2,2)\n2x2 (0,0,2)\n")
    p = str(tmp_path / "pair.png")
    render_pair(before, [0.1, 0.5, 1.3, 0.2], after, [0.1, 0.4, 0.7, 0.2, 0.0], p)
    w, h = _png_size(p)
    assert w > h  # side by side
    _check_png(p)


def test_render_pair_wide_layouts(tmp_path):
    wide = make_layout([str(i) for i in range(6)], [(8 * i, 0, i % 2) for i in range(6)],
                       [(8, 1)] * 6, [3.03e-3] * 6)
    p = str(tmp_path / "pair.png")
    render_pair(wide, np.linspace(0, 1, 6), wide, np.linspace(0, 0.5, 6), p)
    _check_png(p)


def test_render_pair_checks_both_score_arrays(tmp_path):
    lay = _small()
    with pytest.raises(ValueError):
        render_pair(lay, np.zeros(4), lay, np.zeros(3), str(tmp_path / "p.png"))
    assert os.listdir(tmp_path) == []


def test_contact_sheet(tmp_path):
    items = []
    for i in range(5):
        lay = make_layout([str(j) for j in range(i + 1)], [(0, 0, j) for j in range(i + 1)],
                          [(2, 2)] * (i + 1), [1.15e-3] * (i + 1))
        items.append((f"tower {i + 1}", lay, np.linspace(0, 1.1, i + 1)))
    p = str(tmp_path / "sheet.png")
    contact_sheet(items, p, cols=3)
    _check_png(p)
    p1 = str(tmp_path / "one.png")
    contact_sheet(items[:1], p1)  # fewer items than columns
    _check_png(p1)
    assert _leftovers(tmp_path) == []


def test_contact_sheet_errors(tmp_path):
    with pytest.raises(ValueError):
        contact_sheet([], str(tmp_path / "s.png"))
    with pytest.raises(ValueError):
        contact_sheet([("a", _small(), np.zeros(4))], str(tmp_path / "s.png"), cols=0)
    with pytest.raises(ValueError):
        contact_sheet([("a", _small(), np.zeros(2))], str(tmp_path / "s.png"))
    assert os.listdir(tmp_path) == []


@needs_shared
def test_render_reference_stair(tmp_path):
    lay = load_layout(os.path.join(REF, "stair_20.json"))
    scores = np.linspace(0.0, 0.95, lay.n)
    scores[lay.keys.index("2")] = 1.0
    p = str(tmp_path / "stair_20.png")
    render_heatmap(lay, scores, p)
    _check_png(p)


def test_render_1000_bricks(tmp_path):
    rng = np.random.default_rng(0)
    occ = np.zeros((40, 40, 10), bool)
    pos, size = [], []
    shapes = [(1, 1), (1, 2), (2, 1), (2, 4), (4, 2), (2, 2), (1, 8), (8, 1)]
    while len(pos) < 1000:
        sx, sy = shapes[rng.integers(len(shapes))]
        x, y, z = rng.integers(0, 40 - sx), rng.integers(0, 40 - sy), rng.integers(0, 10)
        if occ[x:x + sx, y:y + sy, z].any():
            continue
        occ[x:x + sx, y:y + sy, z] = True
        pos.append((x, y, z))
        size.append((sx, sy))
    lay = make_layout([str(i) for i in range(1000)], pos, size, np.full(1000, 1e-3))
    p = str(tmp_path / "big.png")
    render_heatmap(lay, rng.uniform(0, 1.1, 1000), p)
    _check_png(p)

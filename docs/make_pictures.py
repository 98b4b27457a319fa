"""The pictures of the docs: a PNG heat map, and the 3D pages of a layout and of
a build sequence as headless Chromium shows them (``make docs`` runs this).

Writes ``docs/images/*.png`` and the pages into ``docs/_extra/`` (copied into
the built site). Without Chromium the screenshots already in ``docs/images``
are kept (a note says so). Run from the repository root.
"""
import os
import sys

from stablelego_jax.analysis import analyze
from stablelego_jax.render import render_heatmap
from stablelego_jax.render_html import find_chromium, html_heatmap, screenshot
from stablelego_jax.cli.main import main

HERE = os.path.dirname(os.path.abspath(__file__))
IMAGES, EXTRA = os.path.join(HERE, "images"), os.path.join(HERE, "_extra")
STAIR = os.path.relpath(os.path.join(HERE, "..", "examples", "stablelego", "stair_20.json"))


def run() -> int:
    os.makedirs(IMAGES, exist_ok=True)
    os.makedirs(EXTRA, exist_ok=True)
    a = analyze(STAIR, solver="exact")
    render_heatmap(a.layout, [a.scores[k] for k in a.layout.keys], os.path.join(IMAGES, "stair_20.png"),
                   title="stair_20.json")
    page = os.path.join(EXTRA, "stair_20.html")
    html_heatmap(a.layout, [a.scores[k] for k in a.layout.keys], page, title=STAIR,
                 note=f"{'stable' if a.stable else 'UNSTABLE'}, weakest {a.weakest!r}; drag to turn, hover a brick")
    seq = os.path.join(EXTRA, "stair_20_sequence.html")
    main(["sequence", STAIR, "--solver", "exact", "--html", seq, "--json"])
    if find_chromium() is None:
        print("note: Chromium not installed; docs/images/*_html.png kept as they are", file=sys.stderr)
        return 0
    screenshot(page, os.path.join(IMAGES, "stair_20_html.png"), size=(900, 650))
    screenshot(seq, os.path.join(IMAGES, "sequence_html.png"), size=(900, 650))
    return 0


if __name__ == "__main__":
    sys.exit(run())

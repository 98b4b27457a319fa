"""Dataset objects made from voxels and meshes: merge, analyse, write.

A mesh is voxelised (:mod:`.mesh`), its voxels merged into bricks
(:mod:`.voxels`), the layout analysed (:mod:`stablelego_jax.analysis`) and
written as a StableLego dataset object folder
(:func:`stablelego_jax.formats.dataset.write_object`).
"""
from __future__ import annotations

import dataclasses
import os
import time
from typing import Mapping

import numpy as np

from ..analysis import Analysis, analyze_layout
from ..formats.dataset import write_object
from ..layout import Layout
from .mesh import voxelize
from .stabilize import StabilizeOptions
from .stabilize import stabilize as stabilize_cover
from .voxels import DEFAULT_BRICKS, merge_voxels, parse_bricks

__all__ = ["GeneratedObject", "analyze_and_write", "generate_from_voxels", "generate_from_mesh"]


@dataclasses.dataclass
class GeneratedObject:
    """Summary of one object written by :func:`generate_from_mesh`."""

    name: str
    path: str
    source: str
    n_voxels: int
    n_bricks: int
    stable: bool
    weakest: str
    max_score: float
    n_failing: int
    solver: str
    converged: bool
    time_s: float
    analysis: object = dataclasses.field(default=None, repr=False)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("analysis")
        d["max_score"] = round(self.max_score, 6)
        d["time_s"] = round(self.time_s, 3)
        return d


def analyze_and_write(path: str, layout: Layout, vox: np.ndarray | None = None, *, solver: str = "exact",
                      vis: bool = True, meta: Mapping | None = None, overwrite: bool = False,
                      title: str | None = None) -> Analysis:
    """Analyse ``layout`` with ``solver`` ("exact": HiGHS interior point, the
    fastest on layouts of hundreds of bricks; "jax") and write it as a
    dataset object folder (:func:`~stablelego_jax.formats.dataset.write_object`)
    with its scores; returns the analysis. Nothing is written when the
    layout cannot be written (LayoutError) or ``path`` exists without
    ``overwrite`` (FileExistsError; checked before solving)."""
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"{path}: already exists (use overwrite to replace it)")
    a = analyze_layout(layout, solver=solver, exact_method="highs-ipm", exact_scale=True)
    info = dict(meta or {})
    info.update({"solver": a.solver, "converged": a.converged, "analysis_time_s": round(a.time_s, 4)})
    write_object(path, layout, a.scores, vox=vox, vis=vis, meta=info, overwrite=overwrite, title=title)
    return a


def generate_from_voxels(
    vox: np.ndarray,
    path: str,
    *,
    bricks=DEFAULT_BRICKS,
    seed: int = 0,
    solver: str = "exact",
    vis: bool = True,
    meta: Mapping | None = None,
    overwrite: bool = False,
    source: str = "<voxels>",
    stabilize: StabilizeOptions | None = None,
) -> GeneratedObject:
    """Voxels -> bricks (:func:`merge_voxels`; with ``stabilize``, a cover of
    the same cells that stands where one is found,
    :func:`~stablelego_jax.generate.stabilize.stabilize`) -> analysis ->
    object folder."""
    t0 = time.perf_counter()
    vox = np.asarray(vox).astype(bool)
    bricks = parse_bricks(bricks)
    info = {"seed": int(seed), "bricks": ",".join(f"{a}x{b}" for a, b in bricks)}
    if stabilize is None:
        layout = merge_voxels(vox, seed=seed, bricks=bricks, source=source)
    else:
        if os.path.lexists(path) and not overwrite:  # before the search
            raise FileExistsError(f"{path}: already exists (use overwrite to replace it)")
        r = stabilize_cover(vox, dataclasses.replace(stabilize, bricks=bricks), source=source)
        layout = r.layout
        info["stabilize"] = {k: v for k, v in r.to_json().items() if k != "bricks"}
    info.update(meta or {})
    a = analyze_and_write(path, layout, vox=vox, solver=solver, vis=vis, meta=info, overwrite=overwrite)
    s = a.scores
    return GeneratedObject(
        name=os.path.basename(os.path.normpath(path)), path=os.fspath(path), source=source,
        n_voxels=int(vox.sum()), n_bricks=layout.n, stable=a.stable, weakest=a.weakest,
        max_score=float(s[a.weakest]), n_failing=int(sum(v >= 1.0 for v in s.values())),
        solver=a.solver, converged=a.converged, time_s=time.perf_counter() - t0, analysis=a,
    )


def generate_from_mesh(
    mesh_path: str,
    path: str,
    *,
    grid: int = 20,
    up: str = "auto",
    fill: str = "auto",
    bricks=DEFAULT_BRICKS,
    seed: int = 0,
    solver: str = "exact",
    vis: bool = True,
    overwrite: bool = False,
    stabilize: StabilizeOptions | None = None,
) -> GeneratedObject:
    """Mesh file -> voxels (:func:`~stablelego_jax.generate.mesh.voxelize`) -> bricks ->
    analysis -> dataset object folder ``path``.

    Raises MeshError naming the mesh for an unusable file and
    FileExistsError for an existing ``path`` without ``overwrite``; nothing
    is written then.
    """
    t0 = time.perf_counter()
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"{path}: already exists (use overwrite to replace it)")
    v = voxelize(mesh_path, grid=grid, up=up, fill=fill)
    meta = {"source": os.fspath(mesh_path), "up": v.up, "fill": v.fill, "watertight": v.watertight,
            "pitch": v.pitch, "n_faces": v.n_faces}
    out = generate_from_voxels(v.vox, path, bricks=bricks, seed=seed, solver=solver, vis=vis,
                               meta=meta, overwrite=overwrite, source=os.fspath(mesh_path), stabilize=stabilize)
    out.time_s = time.perf_counter() - t0
    return out

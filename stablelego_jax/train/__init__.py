"""Training a brick-layout generator with the differentiable stability loss.

Modules: :mod:`.shapes` (target shapes, split by object), :mod:`.net` (the
3D conv generator, placements, coverage, decoding), :mod:`.layers` (the
layer-by-layer generator, decoded bottom up), :mod:`.train` (loss,
training loop, checkpoints), :mod:`.evaluate` (held-out scoring with the
exact solver). Command line: ``stablelego train`` and ``stablelego
evaluate``. Needs optax (``pip install 'stablelego-jax[train]'``).
"""
import os as _os

#: The folder of the configs shipped with the package (``default.json``: the result of record).
CONFIGS = _os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "configs")

__all__ = ["CONFIGS"]

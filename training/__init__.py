"""Training a brick-layout generator with the differentiable stability loss (issue 6).

Modules: :mod:`training.shapes` (target shapes, split by object),
:mod:`training.net` (the 3D conv generator, placements, coverage, decoding),
:mod:`training.train` (loss, training loop, checkpoints, CLI),
:mod:`training.evaluate` (held-out scoring with the exact solver, CLI).
"""

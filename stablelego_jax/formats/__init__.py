"""Layout file formats, one module each (import from the module you need):

* :mod:`.reader`: :func:`~.reader.load_layout` (any format, by path) and
  :func:`~.reader.write_layout`;
* :mod:`.stablelego`: StableLego JSON (with a brick library) and the text
  layouts of LLM brick generators;
* :mod:`.ldraw`: LDraw ``.ldr`` files of basic bricks;
* :mod:`.dataset`: StableLego dataset object folders (``vox.npy``,
  ``task_graph.json``, ``stability_score.npy``, ``vis.png``).

Every reader returns a validated :class:`~stablelego_jax.layout.Layout` or
raises :class:`~stablelego_jax.layout.LayoutError` naming the file (and the
brick) at fault; every writer writes atomically.
"""

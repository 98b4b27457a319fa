"""``python -m stablelego_jax ...``: the ``stablelego`` command."""
import sys

from .cli import main

sys.exit(main())

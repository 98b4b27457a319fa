"""Every Python snippet of README.md runs as written, in a fresh interpreter
(float32 JAX, as a user's), from the repository root."""
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


def _snippets():
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_readme_has_python_snippets():
    assert len(_snippets()) >= 2


@pytest.mark.parametrize("i", range(len(_snippets())))
def test_readme_snippet_runs(i):
    code = _snippets()[i]
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, PYTHONPATH=ROOT))
    assert r.returncode == 0, f"README snippet {i}:\n{code}\n--- stderr ---\n{r.stderr[-3000:]}"

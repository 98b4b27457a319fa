"""The shape of the package, read from its source with ``ast``: the import
graph (imports inside functions included) has no cycle, no module imports a
layer above its own, and no private ``_name`` is used outside its module."""
import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")
PKG = "stablelego_jax"

#: The pipeline, bottom up: a module may import its own layer and the ones below.
LAYERS = [
    ("foundations", ("layout", "files", "runtime", "blas", "progress", "geometry", "scene")),
    ("formats", ("formats", "render", "render_scene", "render_html")),
    ("model", ("model", "soft", "score", "contacts", "support")),
    ("solvers", ("solvers",)),
    ("loss", ("loss",)),
    ("analysis", ("analysis", "batch", "design", "sequence")),
    ("generate, train", ("generate", "train")),
    ("cli", ("cli", "__main__")),
]


def _modules():
    """{dotted name: path} of every module of the package."""
    out = {}
    base = os.path.join(ROOT, PKG)
    for d, subdirs, files in os.walk(base):
        subdirs[:] = [s for s in subdirs if not s.startswith((".", "__pycache__"))]
        for f in files:
            if f.endswith(".py"):
                rel = os.path.relpath(os.path.join(d, f), ROOT)[:-3].replace(os.sep, ".")
                out[rel[: -len(".__init__")] if rel.endswith(".__init__") else rel] = os.path.join(d, f)
    return out


MODULES = _modules()


def _layer(mod: str) -> int:
    parts = mod.split(".")
    if len(parts) == 1:
        return len(LAYERS)  # the package facade: above everything (and imports nothing)
    for i, (_, tops) in enumerate(LAYERS):
        if parts[1] in tops:
            return i
    raise AssertionError(f"{mod} is in no layer of tests/test_imports.py")


def _resolve(mod: str, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    pkg = mod.split(".") if os.path.basename(MODULES[mod]) == "__init__.py" else mod.split(".")[:-1]
    pkg = pkg[: len(pkg) - (node.level - 1)]
    return ".".join(pkg + ([node.module] if node.module else []))


def _imports(mod: str):
    """(target module, imported name or None, line) for every import of ``mod``
    that lands in the package."""
    tree = ast.parse(open(MODULES[mod]).read(), MODULES[mod])
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == PKG:
                    yield a.name, None, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(mod, node)
            if base.split(".")[0] != PKG:
                continue
            for a in node.names:
                sub = f"{base}.{a.name}"
                if sub in MODULES:
                    yield sub, None, node.lineno
                else:
                    yield base, a.name, node.lineno


def _graph():
    return {m: sorted({t for t, _, _ in _imports(m) if t in MODULES and t != m}) for m in MODULES}


def test_every_module_has_a_layer():
    for m in MODULES:
        _layer(m)


def test_no_import_of_a_layer_above():
    bad = []
    for m in MODULES:
        for t, _, line in _imports(m):
            if t in MODULES and _layer(t) > _layer(m):
                bad.append(f"{m}:{line} imports {t} ({LAYERS[_layer(m)][0]} -> "
                           f"{LAYERS[_layer(t)][0] if _layer(t) < len(LAYERS) else 'the package facade'})")
    assert not bad, "\n".join(bad)


def test_no_import_cycle():
    graph = _graph()
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for t in graph[m]:
            if state.get(t) == 1:
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(cycles)


def _private_uses(path: str, own: str | None):
    """Private names of package modules used in the file at ``path`` (whose
    module is ``own``, or None for a test or benchmark script)."""
    tree = ast.parse(open(path).read(), path)
    mod = own or os.path.relpath(path, ROOT)
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = _resolve(own, node) if (own and node.level) else (node.module or "")
            if base.split(".")[0] != PKG:
                continue
            for a in node.names:
                sub = f"{base}.{a.name}"
                if sub in MODULES:
                    aliases[a.asname or a.name] = sub
                elif a.name.startswith("_") and not a.name.startswith("__") and base != own:
                    yield f"{mod}:{node.lineno} imports {a.name} from {base}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == PKG and a.asname:
                    aliases[a.asname] = a.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                and node.attr.startswith("_") and not node.attr.startswith("__") and aliases[node.value.id] != own):
            yield f"{mod}:{node.lineno} uses {aliases[node.value.id]}.{node.attr}"


def test_no_private_name_used_outside_its_module():
    bad = [u for m, p in MODULES.items() for u in _private_uses(p, m)]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("folder", ["tests", "benchmarks"])
def test_tests_and_benchmarks_use_the_public_names(folder):
    d = os.path.join(ROOT, folder)
    bad = [u for f in sorted(os.listdir(d)) if f.endswith(".py")
           for u in _private_uses(os.path.join(d, f), None)]
    assert not bad, "\n".join(bad)


def test_the_facade_imports_nothing_and_nothing_imports_it():
    # one exception: blas (standard library only), whose guard must run
    # before JAX's CPU backend starts (see stablelego_jax.blas.one_xla_pool_thread)
    heavy = [t for t, _, _ in _imports(PKG) if t != f"{PKG}.blas"]
    assert not heavy, "stablelego_jax/__init__.py must stay lazy"
    bad = [f"{m}:{line}" for m in MODULES for t, name, line in _imports(m) if t == PKG and m != PKG]
    assert not bad, "modules import the package facade: " + ", ".join(bad)


def test_subpackage_inits_import_nothing_heavy():
    """``import stablelego_jax.formats.reader`` must not pull in the whole
    subpackage: the inits of formats, generate, solvers, design and train
    import none of their modules."""
    for sub in ("formats", "generate", "solvers", "design", "train"):
        assert not [t for t, _, _ in _imports(f"{PKG}.{sub}")], f"{PKG}/{sub}/__init__.py imports modules"

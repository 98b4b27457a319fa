# make demo: create .venv, install, analyse the bundled examples (PNGs in out/)
# make test: create .venv if needed, run the test suite (under 10 min on a 2-core CPU)
# make test-slow: the slow checks that make test leaves out (several compiled variants compared)
# make docs: the docs site (docs/_build/html/index.html) from the guide pages and the docstrings
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test test-slow docs clean

$(BIN)/stablelego: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test,train,html,rows]'
	touch $@

demo: $(BIN)/stablelego
	@mkdir -p out
	$(BIN)/stablelego analyze examples/stablelego/*.json examples/brickgpt/*.txt --solver jax --png out --html out
	$(BIN)/stablelego analyze examples/stablelego/*.json examples/brickgpt/*.txt --solver exact --json > out/exact.jsonl
	@echo "heat maps in out/*.png and out/*.html (3D), exact-solver results in out/exact.jsonl"

test: $(BIN)/stablelego
	$(BIN)/python -m pytest -q -n auto --dist loadfile -m "not slow"

test-slow: $(BIN)/stablelego
	$(BIN)/python -m pytest -q -n auto --dist loadfile -m slow

$(VENV)/.docs: $(BIN)/stablelego
	$(BIN)/pip install -q -e '.[docs]'
	touch $@

docs: $(VENV)/.docs
	$(BIN)/python docs/make_pictures.py > /dev/null
	$(BIN)/sphinx-build -q -b html docs docs/_build/html
	@echo "docs in docs/_build/html/index.html"

clean:
	rm -rf $(VENV) out docs/_build docs/_extra docs/generated

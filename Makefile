# make demo: create .venv, install, analyse the bundled examples (PNGs in out/)
# make test: create .venv if needed, run the test suite
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test clean

$(BIN)/stablelego: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test,train]'
	touch $@

demo: $(BIN)/stablelego
	@mkdir -p out
	$(BIN)/stablelego analyze examples/stablelego/*.json examples/brickgpt/*.txt --png out
	$(BIN)/stablelego analyze examples/stablelego/*.json examples/brickgpt/*.txt --solver exact --json > out/exact.jsonl
	@echo "heat maps in out/*.png, exact-solver results in out/exact.jsonl"

test: $(BIN)/stablelego
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) out

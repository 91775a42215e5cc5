# make demo : set up .venv and run the main job (paper-001 stopping simulation)
# make test : set up .venv and run the whole test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/install_torch.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	bash scripts/install_torch.sh $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(STAMP)

demo: setup
	$(BIN)/train-envs simulate --scenario paper001_stopping --controller pid --out out/demo

test: setup
	$(BIN)/python -m pytest -q -n 2 tests

lint: setup
	$(BIN)/ruff check .

bench: setup
	$(BIN)/python benchmarks/bench_plants.py

clean:
	rm -rf $(VENV) out runs .pytest_cache

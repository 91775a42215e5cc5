# make demo : set up .venv and run the main job: a short MOWOA tuning of paper 004's DMC
#             (SQLite study in out/demo), selected vs default parameters on held-out
#             seeds, Pareto and speed-distance plots in out/demo (~12 s on 2 cores)
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

DEMO_CONFIG := '{"disturbance": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03}}'
DEMO_ARGS := --env TrainEnvs/Urban004-v0 --algo mowoa --pop 12 --iters 5 --seeds 0 1 \
	--holdout-seeds 100 101 102 --config $(DEMO_CONFIG) \
	--constraint max_overspeed_mps=0 --constraint time_error_s=5 --constraint E_p_m=2 \
	--f-lower 0 0 0 0 0 --f-upper 1000 0.5 1 0.1 2.5 \
	--storage sqlite:///out/demo/tuning.db --study 'demo-urban004-{code}' --resume-or-start --out out/demo

demo: setup
	mkdir -p out/demo
	$(BIN)/train-envs tune $(DEMO_ARGS)

test: setup
	$(BIN)/python -m pytest -q -n 2 tests

lint: setup
	$(BIN)/ruff check .

bench: setup
	$(BIN)/python benchmarks/bench_plants.py

clean:
	rm -rf $(VENV) out runs .pytest_cache
	find train_envs -name '*.nbi' -delete -o -name '*.nbc' -delete

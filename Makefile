# Two commands a newcomer needs: `make demo` and `make test`. Each creates .venv and installs what it needs.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
OUT    ?= demo_out

.PHONY: install test demo lint typecheck format bench-envs check-results clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[dev]"
	touch $@

install: $(VENV)/.installed

test: install
	$(PY) -m pytest -q

demo: install
	MPLBACKEND=Agg $(PY) examples/demo.py --out $(OUT)

lint: install
	$(PY) -m ruff check phast_gym phast_model tests examples benchmarks

typecheck: install
	$(PY) -m mypy

format: install
	$(PY) -m ruff format phast_gym phast_model tests examples benchmarks

# re-run the headline PHAST configurations (windy pendulum KNOWN and PARTIAL, seeds 0 and 1, the paper's protocol;
# ~10-20 min) and compare with docs/results/phast_windy.json: run it whenever phast_gym's integrators or phast_model change
check-results: install
	$(PY) benchmarks/phast_windy.py --check --runs WindyPendulum-v0:known WindyPendulum-v0:partial --seeds 0 1

bench-envs: install
	$(PY) benchmarks/envs.py --profile --compiled --out docs/envs_benchmark.json

clean:
	rm -rf $(VENV) demo_out .pytest_cache .ruff_cache

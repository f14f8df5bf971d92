# Two commands do all set-up on a fresh machine:
#   make demo   -- build .venv, install, run the main job
#   make test   -- build .venv, install, run the test suite
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# The CPU build of torch 2.13.0 is installed first and explicitly: an unpinned
# torch would pull a multi-GB CUDA build.
TORCH := torch==2.13.0

$(BIN)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q $(TORCH)
	$(BIN)/pip install -q -e '.[test,fast]'
	touch $@

.PHONY: install demo test docs results
install: $(BIN)/.installed

# the main job: SIP training on heat_2d (the prior stage skips itself: SIP is already within 1 %);
# outputs in runs/demo
demo: install
	$(BIN)/pdeinv train heat_2d --seed 0 --out runs/demo --overwrite

test: install
	$(BIN)/ruff check pdeinv problems tests benchmarks
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist worksteal

# the API reference from the docstrings (pdoc; in the test extra): docs/api/index.html
docs: install
	$(BIN)/python -m pdeinv.util.apidocs docs/api

# docs/results.md: pdeinv train with its default flags on the default scenes, one run at a time
# (benchmarks/results.py; --quick for the n = 16 variants)
results: install
	$(BIN)/python benchmarks/results.py

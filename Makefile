# Every target installs what it needs first: a fresh clone needs only python3 (>= 3.11) and make.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

.PHONY: install warmup demo test test-fast bench lint format clean

install: $(STAMP)

$(STAMP): pyproject.toml scripts/system-deps.sh
	bash scripts/system-deps.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev,bench]"
	$(BIN)/python -m toolkit.warmup
	touch $(STAMP)

warmup: install  ## compile `toolkit map`'s numba kernels into their cache again (after editing them)
	$(BIN)/python -m toolkit.warmup

demo: install    ## import the bundled and real logs, map, label, report into $(OUT)/
	OUT=$(OUT) PATH="$(CURDIR)/$(BIN):$$PATH" bash scripts/demo.sh

test: install    ## the whole test suite, on both cores
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q

test-fast: install  ## the suite without the long end-to-end runs (marked slow), on both cores
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q -m "not slow" -x

bench: install   ## benchmarks side by side in one run; results in $(OUT)/bench/
	$(BIN)/python -m bench --out $(OUT)/bench

SOURCES := $(wildcard toolkit importers reports bench)

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy $(SOURCES)
	$(BIN)/mypy --strict toolkit

format: install
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache

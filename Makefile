# Every target installs what it needs first: a fresh clone needs only python3 (>= 3.11) and make.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

# The seed-pinned real-log tests reproduce diagnosed cases to the bit, and the mapper's last
# bits follow the BLAS kernels OpenBLAS runs (numba's 3 x 3 solves go through its LAPACK). They
# were written where OpenBLAS ran its SkylakeX (AVX-512) kernels; session 40's machine (an AMD
# Zen 5) sets OPENBLAS_CORETYPE=Haswell in its environment and 16 of them failed. Where the CPU
# has AVX-512 the tests ask for SkylakeX's (docs/robustness.md, "Bits and machines").
BLAS_PIN := $(shell grep -qw avx512bw /proc/cpuinfo 2>/dev/null && grep -qw avx512vl /proc/cpuinfo && echo OPENBLAS_CORETYPE=SkylakeX)

.PHONY: install warmup demo test test-fast bench lint format clean constraints

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt scripts/system-deps.sh
	bash scripts/system-deps.sh
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[dev,bench]"
	$(BIN)/python -m toolkit.warmup
	touch $(STAMP)

warmup: install  ## compile `toolkit map`'s numba kernels into their cache again (after editing them)
	$(BIN)/python -m toolkit.warmup

demo: install    ## import the bundled and real logs, map, label, report into $(OUT)/
	OUT=$(OUT) PATH="$(CURDIR)/$(BIN):$$PATH" bash scripts/demo.sh

test: install    ## the whole test suite, on both cores
	$(BLAS_PIN) $(BIN)/python -m pytest -n 2 --dist loadgroup -q

test-fast: install  ## the suite without the long end-to-end runs (marked slow), on both cores
	$(BLAS_PIN) $(BIN)/python -m pytest -n 2 --dist loadgroup -q -m "not slow" -x

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

constraints: install  ## write the installed versions to constraints.txt (once make test passed with them)
	{ sed -n '1,3p' constraints.txt; $(BIN)/python -m pip freeze --exclude-editable; } > constraints.new
	mv constraints.new constraints.txt

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache .ruff_cache

# Two commands set up a fresh machine:
#   make demo   # create .venv, install zcomp, composite the shipped example -> out/demo
#   make test   # create .venv, install zcomp with test extras, run the test suite
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.zcomp-installed

.PHONY: venv demo test test-fast bench bench-intrinsics clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null || \
	  { echo "zcomp needs Python 3.11 (bpy 5.0.1 ships wheels for CPython 3.11 only)."; \
	    echo "Set PYTHON=/path/to/python3.11, e.g. 'make test PYTHON=~/.pyenv/versions/3.11.7/bin/python'."; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -e ".[test,ray]"
	# The reference LPIPS package, for one test only. --no-deps: its torchvision
	# requirement would pull a CUDA build that breaks CPU torch (see README).
	$(BIN)/python -m pip install -q --no-deps lpips==0.1.4
	@touch $@

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/zcomp composite examples/jobs.yaml --out out/demo --overwrite
	@echo "Composites written under out/demo/ (composite.png per job)."

test: $(STAMP)
	$(BIN)/python -m pytest -q -ra

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -ra -m "not blender and not slow"

# The benchmark of issue 4: Cycles ground truth, then every method, then the table.
BENCH_N ?= 20
BENCH_RES ?= 256 256
bench: $(STAMP)
	$(BIN)/python benchmarks/run_benchmark.py --out out/bench --n $(BENCH_N) --resolution $(BENCH_RES)

bench-intrinsics: $(STAMP)
	$(BIN)/python benchmarks/bench_render_intrinsics.py

clean:
	rm -rf out .pytest_cache

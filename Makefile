# Two commands set up a fresh machine:
#   make demo   # create .venv, install zcomp, composite the shipped example -> out/demo
#   make test   # create .venv, install zcomp with test extras, run the test suite
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.zcomp-installed
PIP    := $(BIN)/python -m pip --disable-pip-version-check
# torch's pin, read from pyproject.toml (one place). Where PyPI's default build of it is
# CUDA's (Linux: several GB of CUDA packages), the CPU build is taken from PyTorch's CPU
# index unless a wheel on this machine (pip's find-links) already satisfies the pin.
# Choose another build with TORCH_INDEX (e.g. .../whl/cu126), or TORCH_INDEX= for PyPI's.
TORCH_PIN   := $(shell sed -n 's/^ *"\(torch==[^"]*\)".*/\1/p' pyproject.toml)
TORCH_INDEX ?= $(if $(filter Linux,$(shell uname -s)),https://download.pytorch.org/whl/cpu)

.PHONY: venv demo test test-fast bench bench-intrinsics clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null || \
	  { echo "zcomp needs Python 3.11 (bpy 5.0.1 ships wheels for CPython 3.11 only)."; \
	    echo "Set PYTHON=/path/to/python3.11, e.g. 'make test PYTHON=~/.pyenv/versions/3.11.7/bin/python'."; exit 1; }
	@echo "Creating $(VENV) and installing zcomp (a few minutes; pip's output only on errors)..."
	@$(PYTHON) -m venv $(VENV)
	@$(PIP) install -qq --upgrade pip
	@$(PIP) install -qq --no-index --no-deps "$(TORCH_PIN)" 2>/dev/null || \
	  $(PIP) install -qq "$(TORCH_PIN)" $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX) --extra-index-url https://pypi.org/simple)
	@$(PIP) install -qq -e ".[test,ray]"
	@# The reference LPIPS package, for one test only. --no-deps: its torchvision
	@# requirement would pull a CUDA build that breaks CPU torch (see README).
	@$(PIP) install -qq --no-deps lpips==0.1.4
	@touch $@

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/zcomp composite examples/jobs.yaml --out out/demo --overwrite
	@echo
	@echo "Composites written under out/demo/ (composite.png per job). Next, in this shell or a new one:"
	@echo "  . $(VENV)/bin/activate                                   # zcomp and python from $(VENV) (or call $(BIN)/zcomp)"
	@echo "  zcomp preview-light examples/jobs.yaml --out out/demo    # the light, on three balls"
	@echo "  zcomp report out/demo                                    # one page: open out/demo/report.html"

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

# vcirun: one virtual environment in .venv. Compiled kernels go to the one cache every entry point
# uses (make, the vcirun command, the Python API, the tests): $VCIRUN_CACHE_DIR if set, else
# ~/.cache/vcirun; `vcirun cache info` shows it, `vcirun cache clear` empties it.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin

# Bytecode is written (Python's default) even where the environment sets PYTHONDONTWRITEBYTECODE, for
# what make starts: .venv and the checkout are this project's own (their __pycache__ is git-ignored),
# and without it every process compiles what it imports from source again (`import sympy` 3.5 s against
# 0.6 s from bytecode, matplotlib 2.7 s, on the 2-core machine), in the sweep, its background
# compiles, the plots and each of the test suite's subprocesses.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: run test test-all bench reproduce extremes clean install install-dev

# The packages go in with uv where it can be had (pip puts it in .venv/.uv first, a few seconds): it
# links the wheels from its cache and compiles no bytecode, ~3 s against pip's 30-40 s with both
# caches warm; pip itself goes into the venv too, for the user's own installs. Where uv cannot be
# installed or fails, pip does it all: --no-compile (pip does not byte-compile the dependencies'
# every module, ~25 s; Python compiles the modules vcirun imports on their first import instead),
# pip upgraded only when older than 22 (editable installs of a pyproject need 21.3).
# `install`: what vcirun runs with; `install-dev`: with the test tools and Dask too (the tests and
# benchmarks use them).
UV := $(VENV)/.uv/bin/uv
DEV_EXTRAS := '.[test,dask]'
PIP_INSTALL = ( ( test -x $(UV) || $(PY) -m pip install -q --target $(VENV)/.uv uv >/dev/null 2>&1 ) && \
		$(UV) pip install -q --python $(BIN)/python pip $(1) ) || \
	( ( $(BIN)/python -m pip --version >/dev/null 2>&1 || $(BIN)/python -m ensurepip --default-pip >/dev/null ) && \
		( $(BIN)/python -c 'import pip, sys; sys.exit(int(pip.__version__.split(".")[0]) < 22)' || \
			$(BIN)/python -m pip install -q --upgrade pip ) && $(BIN)/python -m pip install -q --no-compile $(1) )

$(BIN)/vcirun: pyproject.toml
	$(PY) -m venv --without-pip $(VENV)
	@$(call PIP_INSTALL,-e .)
	@touch $@

$(VENV)/.dev: $(BIN)/vcirun
	@$(call PIP_INSTALL,-e $(DEV_EXTRAS))
	@touch $@

install: $(BIN)/vcirun

install-dev: $(VENV)/.dev

# The main job on a small default: sweep configs/quick.yaml and plot it (then, as the README says:
# `source .venv/bin/activate` puts `vcirun` on PATH).
run: install
	$(BIN)/vcirun sweep configs/quick.yaml
	$(BIN)/vcirun plot results/quick.h5
	@echo "next: source $(VENV)/bin/activate, then e.g. vcirun simulate --method MCVAA --beta 4.2 (see README.md)"

# The default test suite (slow tests excluded; `make test-all` runs them too).
test: install-dev
	$(BIN)/python -m pytest -n 2 -q

test-all: install-dev
	$(BIN)/python -m pytest -n 2 -q -m ''

# The full benchmark (about an hour; BENCH_ARGS=--quick for a short smoke run, or
# BENCH_ARGS="--only steps,sim5" for some sections): tables on stdout, JSON and figures in results/.
bench: install-dev
	$(BIN)/python bench/bench_all.py $(BENCH_ARGS)

# The stability study at the extremes (about 6 minutes): docs/extremes.md, results/extremes.json.
extremes: install
	$(BIN)/python bench/extremes_study.py

# Every figure and table of the paper into results/, recomputed from scratch (--force).
reproduce: install
	$(BIN)/vcirun sweep --force configs/fig4.yaml
	$(BIN)/vcirun sweep --force configs/fig3.yaml
	$(BIN)/vcirun sweep --force configs/fig1.yaml
	$(BIN)/vcirun sweep --force configs/table2.yaml
	$(BIN)/vcirun plot results/fig4.h5
	$(BIN)/vcirun plot results/fig3.h5
	$(BIN)/vcirun plot results/fig1.h5
	$(BIN)/vcirun plot results/table2.h5

# (the kernel cache is not the repository's: `vcirun cache clear` empties it)
clean:
	rm -rf $(VENV) build *.egg-info

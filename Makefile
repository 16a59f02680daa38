# vcirun: one virtual environment in .venv. Compiled kernels go to the one cache every entry point
# uses (make, the vcirun command, the Python API, the tests): $VCIRUN_CACHE_DIR if set, else
# ~/.cache/vcirun; `vcirun cache info` shows it, `vcirun cache clear` empties it.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin

.PHONY: run test test-all bench reproduce extremes clean install install-dev

# --no-compile: pip does not byte-compile the dependencies' every module (half of a fresh install,
# ~25 s); Python compiles the modules vcirun imports on their first import instead. pip is upgraded
# only when older than 22 (editable installs of a pyproject need 21.3). `install`: what vcirun runs
# with; `install-dev`: with the test tools and Dask too (the tests and benchmarks use them).
$(BIN)/vcirun: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -c 'import pip, sys; sys.exit(int(pip.__version__.split(".")[0]) < 22)' || \
		$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q --no-compile -e .
	@touch $@

$(VENV)/.dev: $(BIN)/vcirun
	$(BIN)/pip install -q --no-compile -e '.[test,dask]'
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

# Every target does its own set-up: a fresh clone needs only python3 (>= 3.11) and make.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# glibc keeps freed memory instead of re-mapping (and re-zeroing) it every iteration (selfcal/allocator.py)
MALLOC := MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=2147483647 MALLOC_TOP_PAD_=268435456

.PHONY: install suitesparse browser colmap mrcal test test-fast examples docs typecheck demo bench clean

install: suitesparse $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,bench,cholmod]'
	touch $(STAMP)

# scikit-sparse (the cholmod extra) builds against Debian's SuiteSparse headers and a C compiler. CHOLMOD's
# supernodal factorisation runs on the system's libblas.so.3, which Debian resolves to the reference BLAS (or a
# generic ATLAS, which colmap pulls in) unless OpenBLAS is installed: the 5000-image reduced matrix factorises in
# 1.0 s on libopenblas0-pthread against 3.2 s on ATLAS (benchmarks/bench_scaling.py --linalg).
suitesparse:
	@need=""; \
	test -f /usr/include/suitesparse/cholmod.h || need=" libsuitesparse-dev build-essential"; \
	if command -v dpkg-query >/dev/null 2>&1 && \
	   ! dpkg-query -W -f='$${Status}' libopenblas0-pthread 2>/dev/null | grep -q "ok installed"; then \
	  need="$$need libopenblas0-pthread"; fi; \
	test -z "$$need" || { \
	  echo "installing Debian's$$need for CHOLMOD (scikit-sparse) on OpenBLAS"; \
	  SUDO=$$(command -v sudo >/dev/null 2>&1 && [ "$$(id -u)" != 0 ] && echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$need >/dev/null; }

# The report tests open the HTML report in Debian's headless Chromium.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium for the report tests"; \
	  SUDO=$$(command -v sudo >/dev/null 2>&1 && [ "$$(id -u)" != 0 ] && echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq chromium >/dev/null; }

# The dense-workspace tests read the exported model with COLMAP's own reader (colmap model_analyzer).
colmap:
	@command -v colmap >/dev/null 2>&1 || { \
	  echo "installing Debian's colmap for the dense-workspace tests"; \
	  SUDO=$$(command -v sudo >/dev/null 2>&1 && [ "$$(id -u)" != 0 ] && echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq colmap >/dev/null; }

# The uncertainty peer test calibrates the same chessboard with mrcal (Debian's python3-mrcal, imported by the system
# python3 in a subprocess: benchmarks/mrcal_side.py).
mrcal:
	@/usr/bin/python3 -c "import mrcal" >/dev/null 2>&1 || { \
	  echo "installing Debian's python3-mrcal for the projection-uncertainty peer test"; \
	  SUDO=$$(command -v sudo >/dev/null 2>&1 && [ "$$(id -u)" != 0 ] && echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq python3-mrcal >/dev/null; }

# one BLAS thread per test worker: two workers on two cores, not four threads fighting
TEST_ENV := OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 $(MALLOC)

test: install browser colmap mrcal
	$(TEST_ENV) $(PY) -m pytest -q -n 2 --durations=15

# the tests not marked slow (pyproject.toml: whole-block adjustments and the like), for the edit-test loop
test-fast: install browser colmap mrcal
	$(TEST_ENV) $(PY) -m pytest -q -n 2 --durations=15 -m "not slow"

# every shell block of README.md and of the examples' READMEs, the long ones too (tests/test_readme.py; about 15 min)
examples: install browser colmap
	SELFCAL_README_LONG=1 $(TEST_ENV) $(PY) -m pytest -q -n 2 tests/test_readme.py

# the API reference from the docstrings (docs/api), then its examples run as doctests; a warning or a failed
# example fails the build (-E: a fresh environment every time, so that no warning hides in a page read before)
docs: install
	$(PY) -m sphinx -E -W --keep-going -q -b html docs/api docs/_build/html
	$(PY) -m sphinx -E -W --keep-going -q -b doctest docs/api docs/_build/doctest

# mypy with the checks chosen in pyproject.toml ([tool.mypy]) over the whole package
typecheck: install
	$(PY) -m mypy

demo: install
	$(VENV)/bin/selfcal demo --out demo-results

bench: install
	$(PY) benchmarks/bench_spine.py
	$(PY) benchmarks/bench_spine.py --images 1000 --density 0.5
	$(PY) benchmarks/bench_stats.py
	$(PY) benchmarks/bench_batch.py
	$(PY) benchmarks/bench_report.py
	$(PY) benchmarks/bench_colmap.py
	$(PY) benchmarks/robust_peer.py
	$(PY) benchmarks/bench_robust.py
	$(PY) benchmarks/bench_engine.py
	$(PY) benchmarks/bench_scaling.py
	$(PY) benchmarks/bench_workflow.py
	$(PY) benchmarks/bench_pushbroom.py
	$(PY) benchmarks/bench_startup.py
	$(PY) benchmarks/study_trajectory.py --processes 2

clean:
	rm -rf $(VENV) demo-results .pytest_cache docs/_build

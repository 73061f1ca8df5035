# circcal: one-command setup, demo, tests, benchmarks.
# Every target that needs the environment depends on the stamp, so `make test` on a fresh clone sets up first
# and is a no-op setup afterwards.
PY      ?= $(shell command -v python3.11 || command -v python3)
VENV    := .venv
VPY     := $(VENV)/bin/python
STAMP   := $(VENV)/.circcal-setup-stamp
KERNELS := circcal/detector/_aot/.stamp
TORCH   := torch==2.13.0
# The reference versions the conformance bounds and ARCHITECTURE.md's conventions were measured with (pyproject.toml
# allows any OpenCV >= 4.8 to users). A new reference version is an upgrade to re-measure, not a silent change:
# OpenCV 5.1.0.95 (released after these were measured) converges cv2.fisheye.calibrate from its own start where 5.0
# diverged, and moves calibrateCamera on partial boards 7e-6 px from circcal's minimum (5.0: < 1e-6).
PINS    := opencv-contrib-python-headless==5.0.0.93
JOBS    ?= 2

.PHONY: setup demo test lint format bench study study-reports study-paper-2000 study-paper-2000-subset conformance mrcal mrcal-2.5 clean \
        clean-cache chromium realdata-reports

setup: $(STAMP) $(KERNELS)
	@# byte-compiled now, as a pip install does: this environment sets PYTHONDONTWRITEBYTECODE, so without it every
	@# process would compile circcal's modules from source (~0.17 s of a calibrate's start-up)
	@$(VPY) -m compileall -q -j 0 circcal benchmarks >/dev/null

# The detector's kernels compiled ahead of time (circcal/detector/kernels/jit.py: a process then starts without numba);
# rebuilt when a detector module changes (only kernel modules whose source changed are compiled again). A failed
# build is not fatal: the detector then runs under numba's JIT (the same results, ~0.75 s more start-up).
$(KERNELS): $(STAMP) $(wildcard circcal/detector/*.py circcal/detector/*/*.py)
	@$(VPY) -m circcal.detector.kernels.build \
	  || echo "kernels: the ahead-of-time build failed; the detector runs under numba's JIT (slower start-up)"
	@mkdir -p $(dir $(KERNELS)) && touch $(KERNELS)

$(STAMP): pyproject.toml Makefile
	@test -x $(VPY) || $(PY) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip
	@# torch first, pinned: it is the CPU wheel on local disk; unpinned it would pull a multi-GB CUDA build.
	$(VPY) -m pip install -q $(TORCH)
	$(VPY) -m pip install -q -e '.[all]' $(PINS)
	@# lensboy without its declared opencv-contrib-python, which would install a second cv2 over
	@# opencv-contrib-python-headless; lensboy runs on that cv2 (circcal/validators/lensboy.py says where it does not)
	$(VPY) -m pip install -q --no-deps lensboy==4.0.3 \
	  || echo "lensboy: not installed; the lensboy reference will report itself unavailable"
	@$(MAKE) --no-print-directory mrcal
	@$(MAKE) --no-print-directory chromium
	@touch $(STAMP)

# mrcal cannot import beside numpy 2 on Python 3.11: it runs out of process under Debian's /usr/bin/python3.
mrcal:
	@if /usr/bin/python3 -c 'import mrcal' >/dev/null 2>&1; then \
	  echo "mrcal: $$(dpkg-query -W -f='$${Version}' python3-mrcal 2>/dev/null || echo present) (/usr/bin/python3)"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "mrcal: installing Debian's mrcal python3-mrcal (about 1 minute)"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mrcal python3-mrcal) >/dev/null \
	    || echo "mrcal: apt-get install failed; the mrcal reference will report itself unavailable"; \
	else \
	  echo "mrcal: not installed. As root run: apt-get install -y mrcal python3-mrcal"; \
	  echo "       or point CIRCCAL_MRCAL_PYTHON at a Python that can 'import mrcal' (e.g. PyPI mrcal 2.5 on 3.12)"; \
	fi

# The calibration reports of the real photographs (reports/realdata/<set>[-refine-board]/), published with README.md.
REALDATA ?= ../shared/data/realdata
realdata-reports: setup
	@for rb in "" "--refine-board"; do sfx=$${rb:+-refine-board}; \
	  $(VENV)/bin/circcal calibrate $(REALDATA)/boofcv_sony_hx5v_circle_regular_10x8/image*.jpg --grid 8x10 \
	    --pitch 25mm --diameter 15mm --no-progress $$rb --out /tmp/circcal-realdata-10x8.json \
	    --report reports/realdata/boofcv_sony_hx5v_circle_regular_10x8$$sfx || exit 1; \
	  $(VENV)/bin/circcal calibrate $(REALDATA)/boofcv_sony_hx5v_circle_asym_4x5/image*.jpg --grid 5x4 --asymmetric \
	    --pitch 30mm --diameter 20mm --no-progress $$rb --out /tmp/circcal-realdata-4x5.json \
	    --report reports/realdata/boofcv_sony_hx5v_circle_asym_4x5$$sfx || exit 1; \
	done

# The calibration report's browser test (tests/test_calreport.py) loads the report in Debian's chromium, headless;
# without chromium that test skips and says why.
chromium:
	@if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then \
	  echo "chromium: $$( (chromium --version || chromium-browser --version) 2>/dev/null | head -1)"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "chromium: installing Debian's chromium for the report's browser test (about 1 minute)"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null \
	    || echo "chromium: apt-get install failed; the report's browser test will skip and say why"; \
	else \
	  echo "chromium: not installed (the report's browser test skips). As root run: apt-get install -y chromium"; \
	fi

# Optional: PyPI's mrcal 2.5 in its own Python 3.12 venv (its GUI dependency pyfltk is not needed and not built).
# Then: CIRCCAL_MRCAL_PYTHON=$(CURDIR)/.venv-mrcal25/bin/python circcal validate --against mrcal
# (the first python3.12 that runs: a pyenv shim on PATH may exist without 3.12 selected)
PY312 ?= $(shell for p in $$(command -v python3.12) /root/.pyenv/versions/3.12*/bin/python3.12; do \
           "$$p" -c '' >/dev/null 2>&1 && { echo "$$p"; break; }; done)
mrcal-2.5:
	@test -n "$(PY312)" || { echo "mrcal-2.5 needs python3.12"; exit 1; }
	$(PY312) -m venv .venv-mrcal25
	.venv-mrcal25/bin/pip install -q --no-deps mrcal
	.venv-mrcal25/bin/pip install -q numpy numpysane scipy gnuplotlib shapely pyyaml opencv-python-headless
	@echo "export CIRCCAL_MRCAL_PYTHON=$(CURDIR)/.venv-mrcal25/bin/python"

demo: setup
	$(VENV)/bin/circcal demo --require-all

test: setup
	$(VPY) -m pytest -n $(JOBS) -q

study: setup
	$(VPY) -m pytest -n $(JOBS) -q -m slow --ignore=tests/conformance

# The 2,000-run study (studies/paper-2000.yaml: `paper` normal and weak, circcal and OpenCV's pipeline, 500 seeds
# each) on an embedded Dask cluster of $(JOBS) workers; resumable (rerun to finish). 1 h 47 min on the shared 2-core
# machine (reports/studies/paper-2000); the subset (its first 8 seeds, the same run keys) measures the rate. On a cluster:
#   circcal study studies/paper-2000.yaml --scheduler tcp://HOST:8786 --out reports/studies/paper-2000
study-paper-2000: setup
	$(VENV)/bin/circcal study studies/paper-2000.yaml --workers $(JOBS) --out reports/studies/paper-2000

study-paper-2000-subset: setup
	$(VENV)/bin/circcal study studies/paper-2000-subset.yaml --workers $(JOBS) --out reports/studies/paper-2000-subset

# The published study summaries under reports/studies/ (minutes on 2 cores; resumable like every study).
STUDY_REPORTS := monte-carlo solver-batched markers-noise
study-reports: setup
	@for s in $(STUDY_REPORTS); do \
	  $(VENV)/bin/circcal study studies/$$s.yaml --workers $(JOBS) --no-progress --out reports/studies/$$s || exit 1; \
	done

conformance: setup
	$(VPY) -m pytest -n $(JOBS) -q -m 'slow or not slow' tests/conformance

# ruff (lint and format, checked, never rewritten here) and mypy over the typed packages (pyproject.toml's [tool.mypy]);
# `make format` rewrites.
LINTED := circcal tests benchmarks
lint: setup
	$(VENV)/bin/ruff check $(LINTED)
	$(VENV)/bin/ruff format --check $(LINTED)
	$(VENV)/bin/mypy

format: setup
	$(VENV)/bin/ruff check --fix $(LINTED)
	$(VENV)/bin/ruff format $(LINTED)

bench: setup
	$(VPY) -m benchmarks.run

# The environment and build outputs. The rendered fixtures are cached outside the checkout, where
# circcal.fixtures.cache.cache_root() puts them: `make clean-cache` removes them (they re-render on demand).
FIXTURE_CACHE = $(or $(CIRCCAL_CACHE),$(HOME)/.cache/circcal)/fixtures
clean:
	rm -rf $(VENV) .pytest_cache .hypothesis build *.egg-info

clean-cache:
	rm -rf "$(FIXTURE_CACHE)"

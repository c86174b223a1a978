# Setup is two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# torch's supported range, as in pyproject.toml (a test checks they agree). TORCH_INDEX picks the build:
# https://download.pytorch.org/whl/cpu (CPU only, small) or .../whl/cu126 (CUDA 12.6); unset, pip's own
# index decides (on Linux, PyPI's torch is the CUDA build)
TORCH  := torch>=2.13,<2.14
TORCH_INDEX ?=

.PHONY: all venv demo test bench lint docs reference wheel-check clean

all: test

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q '$(TORCH)' $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	# a download from PyPI cut off mid-way (a large wheel) is tried once more
	$(BIN)/python -m pip install -q -e '.[test]' || $(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	PATH="$(CURDIR)/$(BIN):$$PATH" bash examples/demo.sh

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	PATH="$(CURDIR)/$(BIN):$$PATH" bash examples/bench.sh

lint: $(STAMP)
	$(BIN)/ruff check lesscli tests examples tools

# the user guide and the reference (docs/, MkDocs; the optional `docs` extra) into site/
docs: $(STAMP)
	$(BIN)/python -m pip install -q -e '.[docs]'
	$(BIN)/python tools/gen_reference.py
	$(BIN)/mkdocs build --strict

# rewrite docs/reference/ from the CLI's own help (a test fails when a page drifts from it)
reference: $(STAMP)
	$(BIN)/python tools/gen_reference.py

# build the wheel and run it from a fresh venv (torch first, then the wheel alone)
wheel-check: $(STAMP)
	$(BIN)/python -m pip install -q 'build>=1.0'
	PYTHON=$(BIN)/python TORCH='$(TORCH)' bash tools/check_wheel.sh

clean:
	rm -rf $(VENV) demo-out site dist build .pytest_cache

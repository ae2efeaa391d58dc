# Two commands set up a fresh machine: `make serve` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The web viewer (viewer/: three.js bundled by esbuild) is built into service/static/viewer/
# (generated, not committed); node_modules come from package-lock.json through `npm ci`.
VIEWER := service/static/viewer/index.html
VIEWER_MODULES := viewer/node_modules/.package-lock.json

.PHONY: serve test lint bench clean-venv viewer

$(STAMP): pyproject.toml constraints.txt proto/litege.proto | $(VIEWER)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[service,data,dev]'
	$(BIN)/python -m service.grpc_stubs
	touch $(STAMP)

$(VIEWER_MODULES): viewer/package.json viewer/package-lock.json
	cd viewer && npm ci --no-audit --no-fund --loglevel=error

$(VIEWER): $(VIEWER_MODULES) viewer/build.mjs $(wildcard viewer/src/*)
	cd viewer && npm run --silent build

viewer: $(VIEWER)

serve: $(STAMP) $(VIEWER)
	$(BIN)/litege serve

test: $(STAMP) $(VIEWER)
	scripts/ensure_redis.sh
	$(BIN)/ruff check .
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python scripts/bench_descriptor.py

clean-venv:
	rm -rf $(VENV)

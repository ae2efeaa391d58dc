# Two commands set up a fresh machine: `make serve` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: serve test lint bench clean-venv

$(STAMP): pyproject.toml constraints.txt proto/litege.proto
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[service,data,dev]'
	$(BIN)/python -m service.grpc_stubs
	touch $(STAMP)

serve: $(STAMP)
	$(BIN)/litege serve

test: $(STAMP)
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

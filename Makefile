# Two commands set up a fresh machine: `make serve` and `make test`.
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The interpreter the venv is built with: pyproject.toml says requires-python >=3.11,<3.13, so
# the first of python3.11, python3.12 and python3 that runs, is in that range and can make a
# venv (ensurepip: Debian's python3.X-venv). `make PYTHON=/path/to/python3.12` picks one
# explicitly; it is checked the same way. Found only when a venv has to be (re)built.
SUPPORTED_PYTHON := import sys; sys.exit(not (3, 11) <= sys.version_info[:2] < (3, 13))
PYTHON_CANDIDATES := python3.11 python3.12 python3
PYTHON ?= $(firstword $(foreach candidate,$(PYTHON_CANDIDATES),$(shell \
	$(candidate) -c '$(SUPPORTED_PYTHON); import ensurepip' >/dev/null 2>&1 && echo $(candidate))))
# A venv whose interpreter is gone (a removed pyenv/system Python) or unsupported (made with
# 3.13) is rebuilt, not reused: the install step then always runs.
VENV_OK := $(shell $(BIN)/python -c '$(SUPPORTED_PYTHON)' >/dev/null 2>&1 && echo ok)
# Where torch comes from. Empty: pip's own configuration (PyPI's torch==2.13.0 is the CUDA
# build on Linux, several GB). `make TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu`
# installs the CPU-only wheel first, and the package install then keeps it (README).
TORCH_INDEX_URL ?=
# The web viewer (viewer/: three.js bundled by esbuild) is built into service/static/viewer/
# (generated, not committed); node_modules come from package-lock.json through `npm ci`.
# The same build copies Swagger UI (swagger-ui-dist, pinned in viewer/package.json) into
# service/static/docs/, which the service's /docs page loads instead of a CDN.
VIEWER := service/static/viewer/index.html
DOCS_UI := service/static/docs/swagger-ui-bundle.js
VIEWER_MODULES := viewer/node_modules/.package-lock.json

.PHONY: serve test typecheck lint bench clean-venv viewer venv-check

ifneq ($(VENV_OK),ok)
$(STAMP): venv-check
endif
venv-check:
	@: # forces the install step when $(VENV) is missing, broken or made with another Python

$(STAMP): pyproject.toml constraints.txt proto/litege.proto | $(VIEWER)
	@if ! $(BIN)/python -c '$(SUPPORTED_PYTHON)' >/dev/null 2>&1; then \
	    if [ -e $(VENV) ]; then \
	        found=$$($(BIN)/python --version 2>/dev/null || echo "its interpreter is missing"); \
	        echo "$(VENV) is unusable ($$found; LiteGE needs Python 3.11 or 3.12): rebuilding it"; \
	        rm -rf -- '$(VENV)'; \
	    fi; \
	    if [ -z '$(PYTHON)' ]; then \
	        echo "no supported Python found: LiteGE needs Python 3.11 or 3.12 with venv support" \
	             "(tried $(PYTHON_CANDIDATES)); install one (Debian/Ubuntu: apt install" \
	             "python3.11-venv) or run: make PYTHON=/path/to/python3.12" >&2; \
	        exit 1; \
	    fi; \
	    if ! '$(PYTHON)' -c '$(SUPPORTED_PYTHON)' >/dev/null 2>&1; then \
	        echo "PYTHON=$(PYTHON) is $$('$(PYTHON)' --version 2>&1); LiteGE needs Python" \
	             "3.11 or 3.12 (requires-python >=3.11,<3.13)" >&2; \
	        exit 1; \
	    fi; \
	    echo "creating $(VENV) with $(PYTHON) ($$('$(PYTHON)' --version 2>&1))"; \
	    '$(PYTHON)' -m venv '$(VENV)'; \
	fi
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(if $(TORCH_INDEX_URL),$(BIN)/python -m pip install --quiet -c constraints.txt torch \
	    --index-url '$(TORCH_INDEX_URL)')
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[service,data,dev]'
	$(BIN)/python -m service.grpc_stubs
	touch $(STAMP)

$(VIEWER_MODULES): viewer/package.json viewer/package-lock.json
	cd viewer && npm ci --no-audit --no-fund --loglevel=error

$(VIEWER): $(VIEWER_MODULES) viewer/build.mjs $(wildcard viewer/src/*)
	cd viewer && npm run --silent build

# Written by the same build, after the viewer; rebuilt here only when it is missing.
$(DOCS_UI): $(VIEWER)
	test -f $@ || (cd viewer && npm run --silent build)
	touch $@

viewer: $(VIEWER) $(DOCS_UI)

serve: $(STAMP) $(VIEWER) $(DOCS_UI)
	$(BIN)/litege serve

test: $(STAMP) $(VIEWER) $(DOCS_UI)
	scripts/ensure_redis.sh
	$(BIN)/ruff check .
	$(MAKE) --no-print-directory typecheck
	$(BIN)/python -m pytest

# mypy checks the packages listed under [tool.mypy] `files` in pyproject.toml (litege_core and
# service; the generated gRPC stubs in service/_generated/ are excluded there).
typecheck: $(STAMP)
	$(BIN)/mypy

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/python scripts/bench_descriptor.py

# Remove the virtual environment; the next `make serve` / `make test` builds it afresh.
clean-venv:
	rm -rf -- '$(VENV)'

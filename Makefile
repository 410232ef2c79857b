# Bare Earth: set-up, demo, tests and packaging. Every target installs what is missing first.
SHELL := /bin/bash
ROOT := $(CURDIR)
PY := /usr/bin/python3
VENV_PY := $(ROOT)/.venv/bin/python
export QT_QPA_PLATFORM := offscreen
export QGIS_PLUGINPATH := $(ROOT)/.build/plugins
export XDG_RUNTIME_DIR ?= /tmp/runtime-$(shell id -u)
DEMO_DIR ?= $(ROOT)/out/demo
VERSION := $(shell sed -n 's/^version=//p' metadata.txt)

.PHONY: setup demo test lint package clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) scripts/demo.py "$(DEMO_DIR)"

test:
	@bash scripts/setup.sh --venv
	$(VENV_PY) -m pytest -q tests

lint:
	@bash scripts/setup.sh --venv >/dev/null
	$(ROOT)/.venv/bin/ruff check .

# The zip the QGIS plugin repository accepts: one folder bare_earth/ with metadata.txt, __init__.py and
# LICENSE (required since 2024), no caches, no compiled files (tests/test_packaging.py checks it).
package:
	@git ls-files --error-unmatch LICENSE metadata.txt >/dev/null 2>&1 || \
	  { echo "LICENSE and metadata.txt must be committed: the plugin repository refuses a zip without them" >&2; exit 1; }
	@rm -rf .build/package dist && mkdir -p .build/package/bare_earth dist
	@git ls-files | grep -vE '^(tests/|benchmarks/|scripts/|docs/|\.ci/|\.gitignore|Makefile|pytest\.ini|pyproject\.toml)' \
	  | while read f; do mkdir -p ".build/package/bare_earth/$$(dirname "$$f")"; cp "$$f" ".build/package/bare_earth/$$f"; done
	@cd .build/package && zip -qrX "$(ROOT)/dist/bare_earth-$(VERSION).zip" bare_earth -x '*__pycache__*' '*.pyc' '*.pyo' '*.so'
	@rm -rf .build/package
	@echo "dist/bare_earth-$(VERSION).zip"

clean:
	rm -rf .build dist out

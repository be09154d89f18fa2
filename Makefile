# The README's two commands: `make demo` (main job) and `make test` (the test-suite). Both set up first.
.PHONY: setup demo test lint typecheck check protocol

setup:
	./setup.sh

# A second `make demo` refuses to write into the existing demo-out (nothing is overwritten without --overwrite):
# `make demo OVERWRITE=1` passes --overwrite and replaces the earlier demo's files.
demo: setup
	.venv/bin/bracketry demo $(if $(filter 1,$(OVERWRITE)),--overwrite)

test: setup
	.venv/bin/python -m pytest -q

lint:
	.venv/bin/ruff check .

typecheck:
	.venv/bin/mypy

check: lint typecheck test

# Rewrite the generated parts of the wire codec (C, Python, PROTOCOL.md) from firmware/protocol/messages.json.
protocol:
	python3 firmware/protocol/generate.py

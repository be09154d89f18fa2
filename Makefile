# The README's two commands: `make demo` (main job) and `make test` (the test-suite). Both set up first.
.PHONY: setup demo test lint typecheck check

setup:
	./setup.sh

demo: setup
	.venv/bin/bracketry demo

test: setup
	.venv/bin/python -m pytest -q

lint:
	.venv/bin/ruff check .

typecheck:
	.venv/bin/mypy

check: lint typecheck test

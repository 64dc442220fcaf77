# The two commands a fresh machine needs: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
PYTEST_ARGS ?=

.PHONY: venv demo test lint bench clean

venv:
	@VENV=$(VENV) bash tools/setup_venv.sh

demo: venv
	$(PY) -m relaygs.run

test: venv
	$(PY) -m ruff check src tests
	$(PY) -m pytest -q -n auto --dist loadfile $(PYTEST_ARGS)

lint: venv
	$(PY) -m ruff check src tests
	$(PY) -m ruff format --check src tests

bench: venv
	$(PY) -m relaygs.bench splat

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache

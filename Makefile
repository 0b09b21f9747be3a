# The few verbs people type. Everything runs inside .venv (created on first use).
PY := .venv/bin/python
STAMP := .venv/.sensedispatch-installed

.PHONY: install test run demo bench openapi lint

install: $(STAMP)

# Same venv and stamp as scripts/test.sh: reinstall when pyproject.toml changes.
$(STAMP): pyproject.toml
	@test -x $(PY) || { \
		py=$$(command -v python3.11 || command -v python3) && \
		$$py -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' && \
		$$py -m venv .venv; } || { echo "make: Python 3.11 is required" >&2; exit 1; }
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[dev]'
	@touch $(STAMP)

test:
	bash scripts/test.sh $(ARGS)

run: $(STAMP)
	$(PY) -m app run

demo: $(STAMP)
	$(PY) -m app demo

bench: $(STAMP)
	$(PY) -m bench.bench_epoch

openapi: $(STAMP)
	$(PY) -m app openapi

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy services app

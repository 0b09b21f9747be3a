# The few verbs people type. Everything runs inside .venv (created on first use).
PY := .venv/bin/python
STAMP := .venv/.sensedispatch-installed

.PHONY: install test run demo replay experiment bench bench-epoch bench-sim bench-dro openapi lint

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

replay: $(STAMP)
	$(PY) -m app replay $(ARGS)

# The paper's numerical test (resumable; writes docs/results/). ARGS="--seeds 3" etc.
experiment: $(STAMP)
	$(PY) -m app experiment $(ARGS)

# Every benchmark; each writes its own section of docs/PERFORMANCE.md.
bench: bench-epoch bench-sim bench-dro

bench-epoch: $(STAMP)
	$(PY) -m bench.bench_epoch

bench-sim: $(STAMP)
	$(PY) -m bench.bench_sim

bench-dro: $(STAMP)
	$(PY) -m bench.bench_dro

openapi: $(STAMP)
	$(PY) -m app openapi

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy services app

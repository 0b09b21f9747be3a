# The few verbs people type. Everything runs inside .venv (created on first use).
PY := .venv/bin/python
STAMP := .venv/.sensedispatch-installed

.PHONY: install test check lint format run demo replay experiment fleet-experiment bench bench-epoch bench-epoch-redis bench-http-path bench-search bench-sim bench-dro bench-cluster bench-fleet-metro bench-hardening bench-fleet-service bench-fleet-own-city openapi dashboard

install: $(STAMP)

# Same venv and stamp as scripts/test.sh: reinstall when pyproject.toml changes.
$(STAMP): pyproject.toml
	@test -x $(PY) || { \
		py=$$(command -v python3.11 || command -v python3) && \
		$$py -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' && \
		$$py -m venv .venv; } || { echo "make: Python 3.11 is required" >&2; exit 1; }
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[dev,research,cluster]'
	@touch $(STAMP)

test:
	bash scripts/test.sh $(ARGS)

# The gate CI runs before the full suite: formatter check, lint, strict types, the function-size and
# import-circle checks, then the quick tests (everything not marked slow or redis; the full suite, Redis
# included, is `make test`). .pre-commit-config.yaml runs the same as git hooks.
check: lint
	$(PY) -m pytest -q -m "not slow and not redis"

lint: $(STAMP)
	$(PY) -m ruff format --check .
	$(PY) -m ruff check .
	$(PY) -m mypy services app research tests
	$(PY) scripts/check_functions.py
	$(PY) scripts/check_imports.py

# Rewrite the code in the house format and apply ruff's safe fixes.
format: $(STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

run: $(STAMP)
	$(PY) -m app run

demo: $(STAMP)
	$(PY) -m app demo

replay: $(STAMP)
	$(PY) -m app replay $(ARGS)

# The paper's numerical test (resumable; writes docs/results/). ARGS="--seeds 3" etc.
experiment: $(STAMP)
	$(PY) -m research experiment $(ARGS)

# The paper's Table 2: fleet sizing on train/test days (resumable; writes docs/results/).
fleet-experiment: $(STAMP)
	$(PY) -m research fleet-experiment $(ARGS)

# Every benchmark; each writes its own section of docs/PERFORMANCE.md (the Redis one needs a redis-server at
# REDIS_URL, default the local one).
bench: bench-epoch bench-epoch-redis bench-search bench-sim bench-dro bench-cluster bench-fleet-metro bench-hardening bench-fleet-service bench-fleet-own-city

# BASELINE=DIR (a checkout of the previous code, e.g. `git worktree add ../base main`) also times its decide on
# the same epochs: the same-run ratio to the previous code.
bench-epoch: $(STAMP)
	$(PY) -m bench.bench_epoch $(if $(BASELINE),--baseline $(BASELINE))

# The HTTP path with the service on Redis (REDIS_URL, default the local server): its own section.
bench-epoch-redis: $(STAMP)
	$(PY) -m bench.bench_epoch --redis-url $${REDIS_URL:-redis://127.0.0.1:6379/0}

# Where an epoch post's time goes besides the solve, stage by stage, in this process (prints; a minute):
# ARGS="--scenario paper --redis-url redis://127.0.0.1:6379/9" for another scenario or the Redis store.
bench-http-path: $(STAMP)
	$(PY) -m bench.bench_http_path $(ARGS)

# One search of an epoch, and the search structures' memory, on the generated metropolitan city (a few minutes).
bench-search: $(STAMP)
	$(PY) -m bench.bench_search

bench-sim: $(STAMP)
	$(PY) -m bench.bench_sim

bench-dro: $(STAMP)
	$(PY) -m bench.bench_dro

# The re-solve on 2 local processes vs a Dask cluster of 1 and 2 workers (small by default; ARGS=--full).
bench-cluster: $(STAMP)
	$(PY) -m bench.bench_cluster $(ARGS)

# A simulated day of a 5,000-taxi platform on the generated metropolitan city in one engine process, the runs of
# a re-solve on a local Dask cluster, the engine processes a re-solve needs within 45 minutes (about 15 minutes).
bench-fleet-metro: $(STAMP)
	$(PY) -m bench.bench_fleet_metro $(ARGS)

# The whole service as `make run` starts it: a solve request to the recommendation, epochs while it solves;
# also the README's dashboard screenshot.
bench-fleet-service: $(STAMP)
	$(PY) -m bench.bench_fleet_service

# An imported city sized end to end through the API: a generated 60 x 60 street grid imported from CSV, 10 days
# of a 600-taxi platform's epochs posted, a solve to the recommendation (a few minutes). ARGS="--side 10 --taxis
# 24 --days 2 --no-write": a smoke run.
bench-fleet-own-city: $(STAMP)
	$(PY) -m bench.bench_fleet_own_city $(ARGS)

# The hardening probes: hostile body, stalled connection, frozen Redis, schemathesis, Redis Cluster replay.
bench-hardening: $(STAMP)
	$(PY) -m bench.bench_hardening

# Rebuild the dashboard's static files (app/static/dashboard/) from frontend/ with npm; commit the result.
dashboard:
	cd frontend && npm ci --no-audit --no-fund && npm run build

openapi: $(STAMP)
	$(PY) -m app openapi

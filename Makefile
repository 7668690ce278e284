# drivebus: the two commands a fresh machine needs are `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# `make test` runs the tests on this many xdist workers, then the `serial` ones alone
# (tests/conftest.py). The suite mostly waits on simulated wires and subprocesses, so
# more workers than cores pay: on 2 cores the parallel part took 8:10 on 4 workers, 6:11
# to 7:01 on 6 (8:07 beside a CPU-bound process) and 5:45 on 8, for the same 10.5
# minutes of CPU. (Under 6, a test whose line a worker process served failed when the
# pytest process hosting its simulated drives went 340 ms without the CPU: those tests
# give such lines a 1 s response timeout now, tests/machines.py.)
TEST_WORKERS ?= 6

.PHONY: demo test test-install lint docs bench pictures clean

# The tests start some thousand Python processes (the CLI, simulators, services, workers)
# and pytest's workers each import the whole suite: they read the bytecode cache, which
# an environment with PYTHONDONTWRITEBYTECODE set never writes, so each of them compiled
# drivebus (about 0.4 s of CPU a process) and the suite (about 7 s a worker) again. The
# test runs write it (to __pycache__ folders, which git ignores).
test test-py% test-install: export PYTHONDONTWRITEBYTECODE =
.PRECIOUS: .venv-%/.installed

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,docs]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/drivebus demo

test: $(STAMP)
	-@sh .ci/ensure-mbpoll
	-@sh .ci/ensure-mosquitto
	-@sh .ci/ensure-chromium
	$(BIN)/ruff check src tests examples docs/hooks
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal -m 'not install and not serial'; \
	parallel=$$?; $(BIN)/python -m pytest -q -m 'serial and not install' && exit $$parallel

# The suite's parallel part on another supported Python, e.g. `make test-py3.13`, in its
# own venv .venv-3.13 (the interpreter: tests/installs.py finds it on PATH or under pyenv).
# `make test` already installs the wheel on every supported Python (marker `pythons`).
.venv-%/.installed: pyproject.toml
	py=$$($(PY) tests/installs.py $*) && $$py -m venv .venv-$*
	.venv-$*/bin/pip install --quiet --upgrade pip
	.venv-$*/bin/pip install --quiet -e '.[test,docs]'
	touch $@

test-py%: .venv-%/.installed
	-@sh .ci/ensure-mbpoll
	-@sh .ci/ensure-mosquitto
	-@sh .ci/ensure-chromium
	.venv-$*/bin/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal \
		-m 'not install and not serial and not pythons'

# Slow: throwaway venvs and real pip installs (pymodbus beside drivebus, the pymodbus range).
test-install: $(STAMP)
	$(BIN)/python -m pytest -q -m install

docs: $(STAMP)
	$(BIN)/mkdocs build --strict

bench: $(STAMP)
	$(BIN)/drivebus bench

# The README's pictures (docs/img/report.png, docs/img/dashboard.png), in headless Chromium.
pictures: $(STAMP)
	-@sh .ci/ensure-chromium
	$(BIN)/python tests/make_pictures.py

clean:
	rm -rf $(VENV) .venv-3.* build site src/*.egg-info .pytest_cache

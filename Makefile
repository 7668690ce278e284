# drivebus: the two commands a fresh machine needs are `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/drivebus demo

test: $(STAMP)
	-@sh .ci/ensure-mbpoll
	-@sh .ci/ensure-mosquitto
	-@sh .ci/ensure-chromium
	$(BIN)/ruff check src tests examples
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/drivebus bench

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache

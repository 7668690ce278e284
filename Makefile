# drivebus: the two commands a fresh machine needs are `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-install lint docs bench pictures clean

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
	$(BIN)/python -m pytest -q

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
	rm -rf $(VENV) build site src/*.egg-info .pytest_cache

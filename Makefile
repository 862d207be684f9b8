# Two commands do all the set-up on a fresh machine:
#   make demo   -> creates .venv, installs torch (CPU) + thermonet, runs the main job
#   make test   -> same set-up plus Debian's chromium, then ruff, mypy and the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
TORCH  := torch==2.13.0
STAMP  := $(VENV)/.installed

.PHONY: venv demo test bench clean chromium

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet $(TORCH)
	$(PIP) install --quiet -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/thermonet compare configs/default.yaml --out runs/demo --overwrite

# the report test renders report.html in a real headless browser (Debian's chromium)
chromium:
	command -v chromium >/dev/null || (apt-get update && apt-get install -y --no-install-recommends chromium)

test: $(STAMP) chromium
	$(VENV)/bin/ruff check thermonet tests experiments export
	$(VENV)/bin/mypy thermonet
	$(PY) -m pytest -q -n 2 tests

bench: $(STAMP)
	$(PY) experiments/run_all.py

clean:
	rm -rf $(VENV) runs mlflow.db mlruns .pytest_cache

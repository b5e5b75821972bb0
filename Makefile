VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jthermo demo

# --dist loadfile: a test file runs on one worker, so its module-scoped fixtures (fits, tuned
# controllers) are computed once; compiled code is shared through the persistent cache.
test: $(STAMP)
	$(PY) -m pytest -n 2 --dist loadfile -m "not slow" --durations=15

bench: $(STAMP)
	$(PY) -m pip install -q -e ".[dev,bench]"
	$(PY) benchmarks/identification.py
	$(PY) benchmarks/closedloop.py
	$(PY) benchmarks/tuning.py

clean:
	rm -rf $(VENV) runs .pytest_cache

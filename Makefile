VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test docs bench bench-peers clean

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e ".[dev]"
	$(PY) -m compileall -q jthermo   # bytecode now, not in the first command (benchmarks/bytecode_import.py)
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/jthermo demo

# --dist loadfile: a test file runs on one worker, so its module-scoped fixtures (fits, tuned
# controllers) are computed once; compiled code is shared through the persistent cache.
test: $(STAMP)
	$(PY) -m pytest -n 2 --dist loadfile -m "not slow" --durations=15

# The documentation site (mkdocs-material + mkdocstrings) into site/: the generated pages
# (command line, API reference, results) are rewritten first; --strict fails on any warning.
DOCS_STAMP := $(VENV)/.docs-installed

$(DOCS_STAMP): pyproject.toml | $(STAMP)
	$(PY) -m pip install -q -e ".[docs]"
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(PY) docs/gen_pages.py
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# The peers (SIPPY, jax-sysid) in their own environment: jax-sysid pins an older JAX than
# jthermo's, so it cannot share .venv (needs Python <= 3.12).
PEERS := .venv-peers
PEERS_PY := $(PEERS)/bin/python
PEERS_STAMP := $(PEERS)/.installed

$(PEERS_STAMP): benchmarks/requirements-peers.txt
	python3 -m venv $(PEERS)
	$(PEERS_PY) -m pip install -q --upgrade pip
	$(PEERS_PY) -m pip install -q -r benchmarks/requirements-peers.txt
	touch $(PEERS_STAMP)

bench-peers: $(PEERS_STAMP)

bench: $(STAMP) $(PEERS_STAMP)
	$(PY) -m pip install -q -e ".[dev,bench]"
	$(PY) benchmarks/identification.py --peer-python $(PEERS_PY)
	$(PY) benchmarks/peers_fair.py --peer-python $(PEERS_PY)
	$(PY) benchmarks/closedloop.py
	$(PY) benchmarks/tuning.py

clean:
	rm -rf $(VENV) $(PEERS) runs .pytest_cache site

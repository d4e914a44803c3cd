# trackcal: `make demo` and `make test` are all a fresh machine needs.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Test sessions live on a tmpfs when the machine has one: the session store fsyncs every event (power-loss safety,
# which no test simulates), and on a shared disk that alone made the campaign tests 2-3x slower.
TEST_TMP := $(shell test -d /dev/shm && test -w /dev/shm && echo /dev/shm || echo /tmp)

.PHONY: setup test test-slow lint demo bench docs clean

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@command -v $(PY) >/dev/null 2>&1 || { echo "error: $(PY) not found (trackcal needs Python 3.11)"; exit 1; }
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]'
	touch $(STAMP)

test: setup
	$(BIN)/ruff check .
	TMPDIR=$(TEST_TMP) $(BIN)/python -m pytest

test-slow: setup
	TMPDIR=$(TEST_TMP) $(BIN)/python -m pytest -m slow

lint: setup
	$(BIN)/ruff check .

demo: setup
	$(BIN)/trackcal demo

bench: setup
	$(BIN)/python -m bench

# The manual (docs/, mkdocs.yml) into site/; --strict: a broken link, a page outside the nav or a usage marker naming
# no command fails the build
docs: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) build site *.egg-info .pytest_cache .ruff_cache

# trackcal: `make demo` and `make test` are all a fresh machine needs.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# pyright, the analyser of VS Code, pinned: tests/test_layout.py runs it (docs/layout.md)
PYRIGHT := 1.1.414
# Python caches each module's bytecode (__pycache__) by default; a machine that sets PYTHONDONTWRITEBYTECODE (this
# one does) makes every process compile trackcal's modules again: a `trackcal identify` of 30 rows took 0.7 s of CPU
# instead of 0.25 s, and the tests start trackcal processes by the hundred (the README's examples alone, 88)
unexport PYTHONDONTWRITEBYTECODE
# Test sessions live on a tmpfs when the machine has one: the session store fsyncs every event (power-loss safety,
# which no test simulates), and on a shared disk that alone made the campaign tests 2-3x slower.
TEST_TMP := $(shell test -d /dev/shm && test -w /dev/shm && echo /dev/shm || echo /tmp)

.PHONY: setup test test-slow lint demo bench docs clean

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt tests/thirdparty/abb/constraints.txt Makefile
	@command -v $(PY) >/dev/null 2>&1 || { echo "error: $(PY) not found (trackcal needs Python 3.11)"; exit 1; }
	@command -v npm >/dev/null 2>&1 || { echo "error: npm not found (make setup installs pyright with it)"; exit 1; }
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]'
	# the editor's view of the package: one link, so files added later resolve without a re-install (docs/layout.md)
	mkdir -p $(VENV)/links
	ln -sfn ../.. $(VENV)/links/trackcal
	ln -sfn ../../tests $(VENV)/links/tests
	ln -sfn ../../studies $(VENV)/links/studies
	ln -sfn ../../bench $(VENV)/links/bench
	# pinocchio lives where only cmeel's import hook finds it
	ln -sfn "$$($(BIN)/python -c 'import os, pinocchio; print(os.path.dirname(pinocchio.__file__))')" $(VENV)/links/pinocchio
	# the ABB judge: abb-robot-client, unmodified, in a venv of its own (tests/thirdparty/abb/README.md)
	test -x $(VENV)/judge-abb/bin/python || $(PY) -m venv $(VENV)/judge-abb
	$(VENV)/judge-abb/bin/python -m pip install -q -c tests/thirdparty/abb/constraints.txt abb-robot-client
	npm install --prefix $(VENV)/node --no-save --no-audit --no-fund --loglevel=error pyright@$(PYRIGHT)
	touch $(STAMP)

# The suite runs on every core; a module that shares a fixture or names a loopback address of its own (a mock UR
# controller's fixed ports) runs whole on one worker (tests/conftest.py's UnitScheduling: xdist 3.8's own loadgroup
# lost its groups under pytest 9.2). One worker more than the cores: the tests wait on sockets and on the processes
# they start for a quarter of their time (2 workers on 2 cores: 686 s of CPU in 446 s of wall time, 1.5 cores busy;
# 3 workers: 395 s, docs/layout.md). `make test XDIST=` runs it in one process.
XDIST ?= -n $(shell echo $$(( $$(nproc) + 1 ))) --dist loadgroup

test: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	TMPDIR=$(TEST_TMP) $(BIN)/python -m pytest $(XDIST)

test-slow: setup
	TMPDIR=$(TEST_TMP) $(BIN)/python -m pytest $(XDIST) -m slow --timeout 1800

# ruff's formatter is the one layout (issue 37: no `# fmt: skip`); `ruff format .` rewrites what --check names
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

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

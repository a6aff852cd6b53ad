# Two commands: `make demo` and `make test`. Each builds or refreshes .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: venv warmup test demo render-demo lint bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# Compile every numba kernel ahead, with progress (minutes once per clone, then
# a few seconds: everything loads from numba's cache).
warmup: $(STAMP)
	$(BIN)/holo-warmup

# pytest-xdist processes for `make test`: 2 where there are 2 or more cores, none
# (plain pytest) on one core.  Not one per core: most files start real service
# processes (each with its own threads) and some tests bound a time, so a
# 16-core box with 16 workers would oversubscribe; three fresh-clone runs passed
# in a row with 2 (docs/compile-time.md).  `--dist loadfile` keeps each file's
# tests (and its module-scoped services) in one worker.  Override:
# `make test TEST_WORKERS=4`; plain `pytest` (or `pytest -n0`) runs serially.
TEST_WORKERS ?= $(shell $(PYTHON) -c 'import os; \
	n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1; \
	print(2 if n >= 2 else 0)')

test: warmup
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# No `warmup` first: the demo's service compiles what its first frame needs, then
# the rest in the background at low priority (docs/service.md, "First frame first").
demo: $(STAMP)
	$(BIN)/python -m game.commands.make_demo --out demo-out

render-demo: warmup
	$(BIN)/python -m service.commands.render_demo --out render-demo-out

lint: $(STAMP)
	$(BIN)/ruff check service drivers game sim_devices tests

# Every kernel cached first: the Galilean stage runs its plain scatter only once it is
# cached (docs/compile-time.md), and a benchmark should not time compiles either.
bench: warmup
	$(BIN)/python -m pip install --quiet -e '.[peers]' || echo "make bench: the .[peers] extra did not install; the report names the peers it could not start"
	$(BIN)/holo-bench report --out bench-out

clean:
	rm -rf $(VENV) demo-out render-demo-out bench-out bench-out.partial-*

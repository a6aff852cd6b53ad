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

test: warmup
	$(BIN)/python -m pytest -q

demo: warmup
	$(BIN)/python -m game.full_demo --out demo-out

render-demo: warmup
	$(BIN)/python -m service.demo --out render-demo-out

lint: $(STAMP)
	$(BIN)/ruff check service drivers game sim_devices tests

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[peers]' || echo "make bench: the .[peers] extra did not install; the report names the peers it could not start"
	$(BIN)/holo-bench report --out bench-out

clean:
	rm -rf $(VENV) demo-out render-demo-out bench-out

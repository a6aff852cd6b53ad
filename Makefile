# Two commands: `make demo` and `make test`. Each builds or refreshes .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: venv test demo lint bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

demo: $(STAMP)
	$(BIN)/python -m service.demo --out demo-out

lint: $(STAMP)
	$(BIN)/ruff check service drivers game sim_devices tests

bench: $(STAMP)
	$(BIN)/python -m service.bench.render_bench --out bench-out

clean:
	rm -rf $(VENV) demo-out bench-out

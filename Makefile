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
# about 2 s: everything loads from numba's cache).
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
	$(BIN)/holo-bench render --out bench-out/render
	$(BIN)/holo-bench light --out bench-out/light
	$(BIN)/holo-bench filters --out bench-out/filters
	$(BIN)/holo-bench decoders --out bench-out/decoders
	$(BIN)/holo-bench latency --out bench-out/latency
	$(BIN)/holo-bench galilean --sweep --out bench-out/galilean
	$(BIN)/holo-bench sird --out bench-out/sird

clean:
	rm -rf $(VENV) demo-out render-demo-out bench-out

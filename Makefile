# Two commands on a fresh machine: `make run` and `make test`. Each creates .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export SDL_VIDEODRIVER ?= dummy

.PHONY: run test test-slow bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first: this pin resolves to the local CPU wheel; an unpinned torch pulls a CUDA build.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev]' -c constraints.txt
	touch $(STAMP)

# Main job at its small default: the wave policy on all four tasks (metrics table), then a small demonstration
# dataset (resumed, not rewritten, when it is already there) and its bit-exact replay check.
run: $(STAMP)
	$(BIN)/dpr evaluate --policy wave --env all --seeds 0-2
	$(BIN)/dpr collect --env dpr/Navigation-v0 --policy wave --episodes 2 --steps 500 --out runs/datasets/nav9-demo --mcap
	$(BIN)/dpr replay runs/datasets/nav9-demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	$(BIN)/python tools/bench_env.py

clean:
	rm -rf $(VENV) build *.egg-info

# Two commands on a fresh machine: `make run` and `make test`. Each creates .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export SDL_VIDEODRIVER ?= dummy

.PHONY: run test lint test-slow bench clean lerobot-env

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first: this pin resolves to the local CPU wheel; an unpinned torch pulls a CUDA build.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev,distributed]' -c constraints.txt
	touch $(STAMP)

# Main job at its small default: the learning pipeline on Navigation, N=9 (demonstrations of the Markov wave ->
# behaviour cloning -> PPO fine-tuning, beside PPO from scratch for the same env steps, all evaluated against
# the wave policy on unseen seeds), then its table; figures in runs/pipeline/report. Run again, it resumes.
run: $(STAMP)
	$(BIN)/dpr pipeline --out runs/pipeline --shipped models/card.yaml

# The tests spread over the machine's cores (pytest-xdist), at most four processes: on 2 cores about half the time.
PYTEST_WORKERS ?= -n auto --maxprocesses 4
test: $(STAMP)
	$(BIN)/python -m pytest -q $(PYTEST_WORKERS)

# Style kept by machines: lint and import order, formatting, and the layering contract (pyproject.toml).
lint: $(STAMP)
	$(BIN)/ruff check dpr tests tools examples
	$(BIN)/ruff format --check dpr tests tools examples
	$(BIN)/lint-imports

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow $(PYTEST_WORKERS)

bench: $(STAMP)
	$(BIN)/python tools/bench_env.py

# LeRobot's side environment (LeRobot 0.4.4 beside torch 2.13, pinned: tools/lerobot_requirements.txt), for
# docs/lerobot-policies.md; LEROBOT_VENV=PATH builds it elsewhere. dpr itself never imports LeRobot.
LEROBOT_VENV ?= .venv-lerobot
lerobot-env:
	tools/lerobot_env.sh $(LEROBOT_VENV)

clean:
	rm -rf $(VENV) build *.egg-info

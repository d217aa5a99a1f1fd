#!/usr/bin/env bash
# Wheels of what tools/bench_gpu.sh needs beyond torch and numpy, for a GPU machine that has neither a registry nor
# this project's dependencies: the versions installed in .venv, built for that machine's Python (default 3.12).
# Carry the folder there and install it into a side folder before the benchmark:
#   tools/device_wheels.sh [DIR] [PYTHON_VERSION]     # default .whl 3.12
#   python3 -m pip install --no-index --no-deps --target /tmp/site DIR/*.whl && export PYTHONPATH=/tmp/site:$PWD
set -euo pipefail
dir="${1:-.whl}"
python_version="${2:-3.12}"
venv_python="${VENV_PYTHON:-.venv/bin/python}"
[[ -x "$venv_python" ]] || { echo "$venv_python: not found; run make test first to build .venv" >&2; exit 1; }
packages="gymnasium farama-notifications pettingzoo pymunk cffi pycparser stable-baselines3"
pins=$("$venv_python" - $packages <<'PY'
import sys
from importlib.metadata import version
print(" ".join(f"{name}=={version(name)}" for name in sys.argv[1:]))
PY
)
mkdir -p "$dir"
# shellcheck disable=SC2086  # one argument per pin
"$venv_python" -m pip download --quiet --no-deps --only-binary=:all: --python-version "$python_version" \
    --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 \
    --dest "$dir" $pins
ls "$dir"

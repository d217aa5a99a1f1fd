#!/usr/bin/env bash
# Build the LeRobot side environment: a virtualenv beside dpr's own, with LeRobot and what its training code and
# lerobot-eval import, every package pinned to the release this project checked it with.
#
#   tools/lerobot_env.sh [VENV]        (default: .venv-lerobot in the repository root; `make lerobot-env`)
#
# LeRobot 0.4.4 pins torch<2.11, dpr uses torch 2.13: LeRobot is installed without its dependencies and the rest
# pinned in tools/lerobot_requirements.txt; its dataset, training and evaluation code runs on torch 2.13 (docs/lerobot-policies.md).
# Run again, it does nothing when VENV already holds this exact set (a stamp file records it).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${1:-$ROOT/.venv-lerobot}"
PYTHON="${PYTHON:-python3.11}"
LEROBOT_VERSION=0.4.4
LOCK="$ROOT/tools/lerobot_requirements.txt"
STAMP="$VENV/.dpr-lerobot-$LEROBOT_VERSION"
if [ -f "$STAMP" ] && cmp -s "$STAMP" "$LOCK"; then
  echo "$VENV already holds lerobot $LEROBOT_VERSION"; exit 0
fi
test -x "$VENV/bin/python" || "$PYTHON" -m venv "$VENV"
PIP=("$VENV/bin/python" -m pip install --quiet)
"${PIP[@]}" --upgrade pip
"${PIP[@]}" torch==2.13.0                       # first and pinned: the CPU wheel, not a multi-GB CUDA build
"${PIP[@]}" --no-deps "lerobot==$LEROBOT_VERSION"  # its torch<2.11 pin would replace torch 2.13
"${PIP[@]}" -r "$LOCK"
# dpr (from this checkout), the lerobot_env_dpr plugin and the start-up hook that makes torchvision importable
# beside the CPU torch (tools/lerobot_plugin/dpr_lerobot_startup.py) on the environment's path
SITE="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
printf '%s\n%s\n%s\n' "$ROOT" "$ROOT/tools/lerobot_plugin" \
  "import dpr_lerobot_startup; dpr_lerobot_startup.install()" > "$SITE/dpr-lerobot.pth"
"$VENV/bin/python" - <<'PY'
import importlib.metadata as md
import lerobot.scripts.lerobot_train, lerobot.scripts.lerobot_eval, lerobot_env_dpr  # noqa: F401
print("lerobot", md.version("lerobot"), "torch", md.version("torch"), "diffusers", md.version("diffusers"))
PY
cp "$LOCK" "$STAMP"

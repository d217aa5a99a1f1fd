#!/usr/bin/env bash
# Train a recipe of tools/lerobot_recipes on several training seeds, one after another, each resumed where it
# stopped (tools/lerobot_recipe.py train resumes a run that holds a checkpoint and skips a finished one): run it
# again after a stop and it carries on. One thread, lowest priority, a log per seed beside its run folder.
#
#   nohup tools/lerobot_train_seeds.sh diffusion_navigation runs/lerobot/nav80 runs/lerobot/train/diffusion 0 1 2 &
#
# writes runs/lerobot/train/diffusion-s0 (its log runs/lerobot/train/diffusion-s0.log), -s1, -s2.
# LEROBOT_VENV (default .venv-lerobot) is the side environment `make lerobot-env` builds.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PY="${LEROBOT_VENV:-$ROOT/.venv-lerobot}/bin/python"
RECIPE="$1" DATASET="$2" PREFIX="$3"
shift 3
for SEED in "$@"; do
  OUT="$PREFIX-s$SEED"
  echo "$(date -u +%FT%TZ) $RECIPE seed $SEED -> $OUT" >&2
  nice -n 19 env OMP_NUM_THREADS=1 "$PY" "$ROOT/tools/lerobot_recipe.py" train --recipe "$RECIPE" \
    --dataset "$DATASET" --seed "$SEED" --out "$OUT" >> "$OUT.log" 2>&1
done

#!/usr/bin/env bash
# The batched engine's figures on a CUDA machine, in a few minutes: env steps/s from K=1 to 65,536 at N=9 and at
# N = 100 to 10,000 (beside the pymunk disk env on the CPU), then the whole PPO loop against `dpr train` on pymunk.
# Needs the project installed (`make test` does it, or pip install -e . with torch built for CUDA).
#   tools/bench_gpu.sh [OUT_DIR]      # writes bench-batched.json and bench-training.json there
set -euo pipefail
out="${1:-.}"
mkdir -p "$out"
python -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 'no CUDA device: torch.cuda.is_available() is False')"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader || true
python -m dpr.cli bench --engine batched --device cuda --ks 1 64 1024 4096 16384 65536 \
    --batched-sizes 100 1000 10000 --json "$out/bench-batched.json"
# the same at N=9 with each physics substep compiled (Triton kernels on the GPU)
python -m dpr.cli bench --engine batched --device cuda --compile --ks 1024 4096 16384 65536 --batched-sizes \
    --json "$out/bench-batched-compiled.json"
python tools/bench_training.py --device cuda --num-envs 4096 --updates 3 --repeats 1 --json "$out/bench-training.json"

#!/usr/bin/env bash
# The batched engine's figures on a CUDA machine, in about ten minutes: env steps/s from K=1 to 65,536 at N=9 and at
# N = 100 to 10,000 (beside the pymunk disk env on the CPU), the same with a GPU's worth of robots per call, N=9
# compiled, then the whole PPO loop against `dpr train` on pymunk, and a profile of where an env step and a PPO round
# spend their time. Each part has a time limit and the next one runs whatever became of it, so a short lease still
# brings back what finished.
# Needs the project importable (`make test` installs it, or pip install -e . with torch built for CUDA).
#   tools/bench_gpu.sh [OUT_DIR]      # writes bench-*.json and a log per part there
#   PYTHON=python3 PART_SECONDS=150 PYMUNK_PROCESSES=16 tools/bench_gpu.sh OUT_DIR
#   PARTS="bench-batched bench-training" tools/bench_gpu.sh OUT_DIR   # only these parts: one short call each
set -uo pipefail
out="${1:-.}"
python="${PYTHON:-python}"
limit="${PART_SECONDS:-150}"
processes="${PYMUNK_PROCESSES:-$(nproc)}"  # the pymunk side of the training loop gets the machine's cores
parts="${PARTS:-}"  # empty: every part
all_parts="bench-batched bench-training bench-batched-large bench-batched-compiled profile-batched"  # the part calls' names below
for name in $parts; do
    [[ " $all_parts " == *" $name "* ]] || { echo "PARTS: no part named '$name' (expected any of: $all_parts)" >&2; exit 2; }
done
mkdir -p "$out"
"$python" -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 'no CUDA device: torch.cuda.is_available() is False')" || exit 1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
"$python" -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
nproc

part() {  # part NAME SECONDS COMMAND...: run it under a limit, its output beside the others (if PARTS names it)
    local name="$1" seconds="$2"
    shift 2
    [[ -z "$parts" || " $parts " == *" $name "* ]] || return 0
    echo "== $name (at most ${seconds} s)"
    local started=$SECONDS
    timeout -s INT -k 10 "$seconds" "$@" 2>"$out/$name.log"
    echo "== $name: exit $? after $((SECONDS - started)) s"
}

part bench-batched "$limit" "$python" -m dpr.cli bench --engine batched --device cuda \
    --ks 1 64 1024 4096 16384 65536 --batched-sizes 100 1000 10000 --json "$out/bench-batched.json"
part bench-training "$limit" "$python" tools/bench_training.py --device cuda --num-envs 4096 --updates 3 \
    --n-envs "$processes" --threads "$processes" --repeats 1 --json "$out/bench-training.json"
# the --batched-sizes rows with 100 times the robots per call: a GPU is not full at 10,000
part bench-batched-large "$limit" "$python" -m dpr.cli bench --engine batched --device cuda --ks 4096 \
    --batched-sizes 100 1000 10000 --batched-robots 1000000 --json "$out/bench-batched-large.json"
# N=9 with each physics substep compiled (Triton kernels on the GPU)
part bench-batched-compiled "$limit" "$python" -m dpr.cli bench --engine batched --device cuda --compile \
    --ks 1024 4096 16384 65536 --batched-sizes --json "$out/bench-batched-compiled.json"
# where a compiled env step (K=4,096) and a PPO round (1,024 envs) spend their time: kernels, launches, host waits
# (twice the limit: it compiles the physics for two sizes and the loss before it profiles)
part profile-batched "$((limit * 2))" "$python" tools/profile_batched.py --device cuda --compile --out "$out/profile-batched"

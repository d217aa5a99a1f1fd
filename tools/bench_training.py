"""The whole PPO loop's env steps per second: `dpr train` on the pymunk disk env against `dpr train --engine batched`,
measured in one run.

Both train the swarm actor (SwarmPolicy) on the same task and env kwargs (the last action observed, a decision every
6 physics steps), each with what `dpr train` takes by default: the pymunk run in SB3's loop with the env id's entry
of ppo.yml (10 epochs of 64-step mini-batches) and `--n-envs` processes, the batched run in dpr.rl.batched_ppo's loop
with the `batched` preset (10 epochs of 512) on `--num-envs` envs of the batched engine. Each rate counts the steps
of the whole run, rollouts and updates together (model building and saving excluded). The two sides run in turn,
`--repeats` pairs, and the ratio is the median of the pairs' ratios.

    python tools/bench_training.py [--env dpr/Navigation-v0] [--num-envs 1024] [--device cpu] [--compile]
                                   [--threads 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

import torch

import dpr  # noqa: F401
from dpr.rl.batched_train import train_batched
from dpr.rl.train import TrainConfig, train

ENV_KWARGS = {"obs_last_action": True, "action_repeat": 6}


def pymunk_rate(env_id: str, n_envs: int, timesteps: int) -> float:
    config = TrainConfig(
        "ppo",
        env_id,
        robot_model="disk",
        timesteps=timesteps,
        n_envs=n_envs,
        env_kwargs=ENV_KWARGS,
        hyperparams={"policy": "SwarmPolicy"},
        eval_episodes=0,
    )
    with tempfile.TemporaryDirectory() as folder:
        result = train(config, Path(folder) / "run", show_progress=False, log=lambda line: None)
    return result.timesteps / result.seconds


def batched_rate(
    env_id: str, num_envs: int, device: str, updates: int, compile: bool = False, threads: int = 2
) -> float:
    torch.set_num_threads(threads)  # a pymunk run before it left one (its SB3 model trains beside env processes)
    config = TrainConfig(
        "ppo",
        env_id,
        robot_model="disk",
        n_envs=num_envs,
        preset="batched",
        engine="batched",
        device=device,
        compile=compile,
    )
    hyper, _, _ = config.resolve()
    timesteps = updates * num_envs * hyper.algo_kwargs["n_steps"]
    config = TrainConfig(**{**config.__dict__, "timesteps": timesteps})
    with tempfile.TemporaryDirectory() as folder:
        result = train_batched(config, Path(folder) / "run", show_progress=False, log=lambda line: None)
    return result.timesteps / result.seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--n-envs", type=int, default=2, help="pymunk: envs in subprocesses (default 2, the cores)")
    parser.add_argument(
        "--pymunk-timesteps", type=int, default=8192, help="pymunk: whole rollouts of n_steps x n_envs (default 8192)"
    )
    parser.add_argument("--num-envs", type=int, default=1024, help="batched: envs per call (default 1024)")
    parser.add_argument("--updates", type=int, default=3, help="batched: PPO updates per run (default 3)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2, help="torch threads of the batched run (default 2)")
    parser.add_argument(
        "--compile", action="store_true", help="batched: torch.compile the physics (a first, untimed run compiles)"
    )
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    if args.compile:  # compiled once here; the timed runs find the compiled code in inductor's cache
        batched_rate(args.env, args.num_envs, args.device, 1, compile=True, threads=args.threads)
    pymunks, batcheds = [], []
    for _ in range(args.repeats):  # in pairs, so that the machine's drift between runs falls on both sides
        pymunks.append(pymunk_rate(args.env, args.n_envs, args.pymunk_timesteps))
        batcheds.append(batched_rate(args.env, args.num_envs, args.device, args.updates, args.compile, args.threads))
    ratios = [batched / pymunk for pymunk, batched in zip(pymunks, batcheds)]
    pymunk, batched, ratio = (statistics.median(values) for values in (pymunks, batcheds, ratios))
    print("| loop | env steps/s (median) | each run | ratio |\n|---|---:|---|---:|")
    each = lambda rates: ", ".join(f"{rate:,.0f}" for rate in rates)  # noqa: E731
    print(f"| dpr train, pymunk disk, {args.n_envs} processes | {pymunk:,.0f} | {each(pymunks)} | 1.0 |")
    label = f"dpr train --engine batched, {args.num_envs} envs, {args.device}{', compiled' if args.compile else ''}"
    runs = ", ".join(f"{value:.1f}x" for value in ratios)
    print(f"| {label} | {batched:,.0f} | {each(batcheds)} | {ratio:.1f} (median of {runs}) |")
    if args.json:
        record = {"pymunk": pymunk, "batched": batched, "ratio": ratio, "ratios": ratios, "args": vars(args)}
        Path(args.json).write_text(json.dumps(record, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

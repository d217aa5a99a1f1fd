#!/usr/bin/env python
"""Where the batched engine's time goes on a device: torch.profiler over env steps and over one PPO round.

For each of the two it writes the profiler's table of ops (sorted by device time on CUDA, by CPU time otherwise)
and a summary in ``profile.json``: wall time a step (or a round), kernels launched, host waits (synchronisations) and
memory copies a step, and the device's busy time against the wall time. A device busy for a small share of
the wall time waits for Python and kernel launches (fewer, larger kernels or CUDA graphs help); one busy nearly all
the time is bound by its kernels.

    python tools/profile_batched.py --device cuda --compile --out OUT      # K=4,096 env steps, a round on 1,024
    python tools/profile_batched.py --num-envs 64 --ppo-envs 16 --steps 2  # small, on the CPU
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

import dpr  # noqa: F401
from dpr.rl import batched_ppo
from dpr.rl.batched_train import build_batched_run
from dpr.rl.train import TrainConfig

LAUNCHES = ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel", "cuLaunchKernelEx")
WAITS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize")
COPIES = ("cudaMemcpy", "cudaMemcpyAsync")


def _learner(env_id: str, num_envs: int, n_robots: int, device: str, compile: bool, hyperparams: dict):
    """The batched preset's env and learner (``hyperparams`` over the preset's), as `dpr train --engine batched`
    builds them."""
    config = TrainConfig(
        "ppo",
        env_id,
        n_robots=n_robots,
        robot_model="disk",
        n_envs=num_envs,
        preset="batched",
        engine="batched",
        device=device,
        compile=compile,
        hyperparams=hyperparams,
    )
    run = build_batched_run(config)
    return run.venv.unwrapped, run.model


def _profiled(work, device: str, repeats: int) -> tuple[profile, float]:
    """``work()`` once to warm up (and compile), then ``repeats`` times under the profiler; the wall time of one."""
    work()
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.startswith("cuda") else [])
    with profile(activities=activities) as prof:
        started = time.perf_counter()
        for _ in range(repeats):
            work()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        wall = (time.perf_counter() - started) / repeats
    return prof, wall


def _device_time(events) -> str:
    """The column of each op's own device time: torch before 2.4 named it after CUDA."""
    return (
        "self_device_time_total"
        if all(hasattr(e, "self_device_time_total") for e in events)
        else "self_cuda_time_total"
    )


def _summary(prof: profile, wall: float, repeats: int, device: str) -> dict:
    events = prof.key_averages()
    count = lambda names: sum(e.count for e in events if e.key in names) / repeats  # noqa: E731
    busy = sum(getattr(e, _device_time(events)) for e in events) / 1e6 / repeats  # the device's kernels, seconds
    return {
        "wall_seconds": wall,
        "kernel_launches": count(LAUNCHES),
        "host_waits": count(WAITS),
        "memory_copies": count(COPIES),
        "device_busy_seconds": busy if device.startswith("cuda") else None,
        "device_busy_share": busy / wall if device.startswith("cuda") else None,
    }


def _table(prof: profile, device: str, rows: int) -> str:
    events = prof.key_averages()
    key = _device_time(events) if device.startswith("cuda") else "self_cpu_time_total"
    return events.table(sort_by=key, row_limit=rows, max_name_column_width=70)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="dpr/Navigation-v0")
    parser.add_argument("--n-robots", type=int, default=9)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--compile", action="store_true", help="torch.compile the physics and PPO's loss")
    parser.add_argument("--num-envs", type=int, default=4096, help="envs of the env-step profile (default 4,096)")
    parser.add_argument("--steps", type=int, default=8, help="env steps profiled (default 8)")
    parser.add_argument("--ppo-envs", type=int, default=1024, help="envs of the PPO round's profile (default 1,024)")
    parser.add_argument("--n-steps", type=int, help="the PPO round's rollout length (default: the batched preset's)")
    parser.add_argument("--rows", type=int, default=30, help="ops in each table (default 30)")
    parser.add_argument("--out", default="profile-batched", help="a new folder for the tables and profile.json")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if out.exists():  # never over an earlier profile
        parser.error(f"--out: {out} exists; name a new folder")
    out.mkdir(parents=True)

    hyperparams = {} if args.n_steps is None else {"n_steps": args.n_steps}
    env, _ = _learner(args.env, args.num_envs, args.n_robots, args.device, args.compile, hyperparams)
    env.reset_tensors(0)
    actions = torch.as_tensor(env.action_space.sample(), device=env.device)
    prof, wall = _profiled(lambda: env.step_tensors(actions), args.device, args.steps)
    summary = {"env_step": {"num_envs": args.num_envs, **_summary(prof, wall, args.steps, args.device)}}
    (out / "env_step.txt").write_text(_table(prof, args.device, args.rows))

    env, model = _learner(args.env, args.ppo_envs, args.n_robots, args.device, args.compile, hyperparams)
    one_round = model.n_steps * args.ppo_envs
    prof, wall = _profiled(lambda: batched_ppo.learn(model, env, one_round, 0, compile=args.compile), args.device, 1)
    summary["ppo_round"] = {"num_envs": args.ppo_envs, "samples": one_round, **_summary(prof, wall, 1, args.device)}
    (out / "ppo_round.txt").write_text(_table(prof, args.device, args.rows))

    summary["args"] = vars(args)
    (out / "profile.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({name: summary[name] for name in ("env_step", "ppo_round")}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

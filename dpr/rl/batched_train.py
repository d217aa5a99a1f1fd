"""``dpr train --engine batched``: a PPO run on the batched disk engine, written as ``dpr train`` writes one.

The run folder holds ``config.yaml`` (what the run was asked and what it made, the engine and device among it),
``model.zip`` (an ordinary PPO model file, runnable on either engine) and ``progress.yaml`` (per-update statistics).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import torch
import yaml
from tqdm import tqdm

from dpr import runs
from dpr.policies.sb3 import ModelInfo, model_architecture, save_model
from dpr.rl.batched_ppo import build_learner, learn


def train_batched(
    config,
    out: str | Path | None = None,
    *,
    show_progress: bool = True,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
):
    """Train ``config`` (a :class:`dpr.rl.train.TrainConfig` with ``engine="batched"``) with the tensor PPO of
    :mod:`dpr.rl.batched_ppo` on ``config.n_envs`` envs of the batched engine; a :class:`TrainResult`."""
    from dpr.rl.train import TrainResult, prepare_run_dir

    hyper, env_kwargs, timesteps = config.resolve()
    venv = gym.make_vec(
        config.env_id,
        num_envs=config.n_envs,
        vectorization_mode="vector_entry_point",
        max_episode_steps=config.steps_per_episode,
        device=config.device,
        **config.training_kwargs(env_kwargs),
    )  # bad kwargs, a device without CUDA or a swarm too large for memory fail here, before the run folder exists
    torch.manual_seed(config.seed)
    model = build_learner(hyper, venv.unwrapped.template, config.seed)
    run_dir = prepare_run_dir(out, config)
    record = {
        "algo": config.algo,
        "engine": config.engine,
        "device": config.device,
        "env_id": config.env_id,
        "env_kwargs": env_kwargs,
        "steps_per_episode": config.steps_per_episode,
        "hyperparameters": hyper.as_dict(),
        "seed": config.seed,
        "n_envs": config.n_envs,
        "timesteps": timesteps,
        "versions": runs.package_versions(),
        "config": asdict(config),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    config_path = run_dir / "config.yaml"
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    log(f"dpr train: ppo on the batched engine ({config.device}, {config.n_envs} envs), {config.env_id} {env_kwargs}")
    started = time.perf_counter()
    with tqdm(total=timesteps, desc=f"train ppo {config.env_id}", unit="step", disable=not show_progress) as bar:
        history = learn(model, venv.unwrapped, timesteps, config.seed, progress=bar)
    seconds = time.perf_counter() - started
    venv.close()
    info = ModelInfo(
        config.algo, config.env_id, env_kwargs, config.steps_per_episode, architecture=model_architecture(hyper)
    )
    model_path = save_model(model, run_dir / "model.zip", info)
    (run_dir / "progress.yaml").write_text(yaml.safe_dump(history, sort_keys=False))
    made = int(model.num_timesteps)
    record.update(seconds=round(seconds, 1), timesteps_done=made, env_steps_per_second=round(made / seconds, 1))
    record["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    log(f"dpr train: wrote {model_path} ({made} steps in {seconds:.0f} s, {made / seconds:,.0f} env steps/s)")
    return TrainResult(run_dir, model_path, config_path, None, timesteps, seconds)

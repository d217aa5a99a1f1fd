"""Snapshots of a ``dpr train --engine batched`` run, and resuming from one to the model an uninterrupted run makes.

After an update (every :data:`dpr.rl.resume.SNAPSHOT_SECONDS`, or as often as asked) the run writes
``<run>/resume/batched.pt``: the policy's and its optimizer's state dicts, the number of updates done and the
model's step count, the statistics so far, the observation the next rollout starts from, the vector env's whole
state (every tensor of the env and of its :class:`~dpr.sim.batched.BatchedDiskWorld`: positions, velocities,
trackers and the solver's carried impulses, and each env's start generator) and the torch, numpy and Python random
states. Resuming builds the run's model and env again as the run built them, puts all of it back and goes on with
the next update, so the final model is the one the run would have made without the stop, weight for weight (on the
same device: :mod:`tests.test_batched_resume`).

The file is read by torch with ``weights_only=True``: tensors and plain values only, nothing that runs code. A
snapshot replaces the last one only once written whole (``batched.pt.new`` renamed onto it).
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dpr.checks import ParameterError
from dpr.rl.resume import SNAPSHOT_DIR

SNAPSHOT_FILE = "batched.pt"
VERSION = 1


def snapshot_file(run_dir: str | Path) -> Path:
    return Path(run_dir) / SNAPSHOT_DIR / SNAPSHOT_FILE


def _tensors(obj) -> dict[str, torch.Tensor]:
    return {name: value.clone() for name, value in vars(obj).items() if isinstance(value, torch.Tensor)}


def env_state(env) -> dict[str, Any]:
    """Everything that changes as the batched vector env ``env`` steps: its tensors, its world's, and each env's
    start generator."""
    return {
        "env": _tensors(env),
        "world": env.world.state_dict(),
        "generators": [generator.bit_generator.state for generator in env._generators],
        "started": bool(env._started),
    }


def load_env_state(env, state: dict[str, Any]) -> None:
    """Put ``state`` (from :func:`env_state` of an env of the same settings) back into ``env``."""
    for name, value in state["env"].items():
        current = getattr(env, name, None)  # (None: made by the first reset, as _last_observation is)
        if isinstance(current, torch.Tensor) and current.shape != value.shape:
            raise ValueError(f"the snapshot's {name} does not fit this run's env")
        setattr(env, name, value.to(env.device))
    env.world.load_state_dict(state["world"])
    for generator, generator_state in zip(env._generators, state["generators"], strict=True):
        generator.bit_generator.state = generator_state
    env._started = state["started"]


@dataclass
class LoopState:
    """Where the PPO loop of :func:`dpr.rl.batched_ppo.learn` stands between two updates."""

    updates: int  # done so far
    observation: torch.Tensor  # what the next rollout starts from
    history: list[dict[str, Any]]


def _random_states() -> dict[str, Any]:
    numpy_state = np.random.get_state()
    states = {
        "torch": torch.get_rng_state(),
        "numpy": [numpy_state[0], torch.from_numpy(numpy_state[1].astype(np.int64)), *numpy_state[2:]],
        "python": random.getstate(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def _restore_random_states(states: dict[str, Any]) -> None:
    torch.set_rng_state(states["torch"])
    name, keys, *rest = states["numpy"]
    np.random.set_state((name, keys.numpy().astype(np.uint32), *rest))
    random.setstate(states["python"])
    if "cuda" in states:
        torch.cuda.set_rng_state_all(states["cuda"])


def save_batched_snapshot(run_dir: str | Path, model, env, loop: LoopState) -> None:
    """Write the run's state after ``loop.updates`` updates (module docstring)."""
    path = snapshot_file(run_dir)
    path.parent.mkdir(exist_ok=True)
    state = {
        "version": VERSION,
        "policy": model.policy.state_dict(),
        "optimizer": model.policy.optimizer.state_dict(),
        "num_timesteps": int(model.num_timesteps),
        "updates": loop.updates,
        "observation": loop.observation.cpu(),
        "history": loop.history,
        "env": env_state(env),
        "random": _random_states(),
    }
    fresh = path.with_name(path.name + ".new")
    torch.save(state, fresh)
    fresh.replace(path)


def resume_batched(run_dir: str | Path, model, env) -> LoopState:
    """Put the snapshot in ``run_dir`` into ``model`` and ``env`` (built as the stopped run built them), and the
    random states back; where the loop goes on from. A ParameterError about ``out`` when there is none."""
    path = snapshot_file(run_dir)
    if not path.is_file():
        raise ParameterError("out", f"{run_dir} holds no snapshot of a stopped batched run ({path})")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 (any unreadable file: named, nothing run)
        raise ParameterError("out", f"{path}: not a snapshot dpr can read ({error})") from None
    if not isinstance(state, dict) or state.get("version") != VERSION:
        raise ParameterError("out", f"{path}: not a version-{VERSION} snapshot of a batched run")
    model.policy.load_state_dict(state["policy"])
    model.policy.optimizer.load_state_dict(state["optimizer"])
    model.num_timesteps = state["num_timesteps"]
    load_env_state(env, state["env"])
    _restore_random_states(state["random"])
    return LoopState(state["updates"], state["observation"].to(env.device), list(state["history"]))

"""``dpr train --engine batched``: a run on the batched disk engine, written as ``dpr train`` writes one.

The run folder holds ``config.yaml`` (what the run was asked and what it made, the engine, device and learner among
it), ``model.zip`` (an ordinary SB3 model file, runnable on either engine), ``progress.yaml`` (per-update
statistics) and ``checkpoints/`` (as ``dpr train`` writes them). The learner is the tensor PPO
of :mod:`dpr.rl.batched_ppo` (``learner="torch"``), or SB3's own ``learn()`` through the ``VecEnv`` adapter of
:mod:`dpr.rl.sb3_batched` (``learner="sb3"``: any SB3 algorithm).

A tensor-PPO run keeps a snapshot of its training state in ``resume/`` (:mod:`dpr.rl.batched_resume`), written after
an update once every :data:`dpr.rl.resume.SNAPSHOT_SECONDS`; ``resume=True`` goes on from it to the model the run
would have made without the stop. Ctrl-C saves the model as it is, keeps the snapshot and returns
``interrupted=True``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import NamedTuple

import gymnasium as gym
import torch
import yaml
from tqdm import tqdm

from dpr import runs
from dpr.checks import ParameterError
from dpr.envs.batched import refuse_batched_only_kwargs
from dpr.policies.distributions import unchecked_distributions
from dpr.policies.model_file import ModelInfo, model_architecture
from dpr.policies.sb3 import build_model, save_model
from dpr.rl import resume as resume_state
from dpr.rl.batched_ppo import build_learner, learn
from dpr.rl.batched_resume import resume_batched, save_batched_snapshot, snapshot_file
from dpr.rl.train import TrainResult, checkpoint_spacing, prepare_run_dir

SB3_LEARNER = "sb3"


def _check_resume(config, out) -> None:
    """A ParameterError about ``out`` unless it holds a stopped tensor-PPO run of ``config`` with a snapshot."""
    if config.learner == SB3_LEARNER:
        raise ParameterError("resume", "a run of SB3's learner on the batched engine does not resume; start it again")
    if out is None or not snapshot_file(out).is_file():
        raise ParameterError("out", f"{out} holds no snapshot of a stopped batched run to resume from")
    resume_state.check_recorded_settings(out, asdict(config), resume_state.added_later(config))


def batched_resumable(out, config) -> bool:
    """Whether ``out`` holds a stopped tensor-PPO run of ``config`` to resume (changes nothing)."""
    try:
        _check_resume(config, out)
    except (ParameterError, OSError, AttributeError):
        return False
    return True


def _run_record(config, hyper, env_kwargs: dict, timesteps: int) -> dict:
    return {
        "algo": config.algo,
        "engine": config.engine,
        "device": config.device,
        "torch_threads": torch.get_num_threads(),  # the sums' order, so the run's last digits, may depend on it
        "learner": config.learner,
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


class BatchedRun(NamedTuple):
    """What :func:`build_batched_run` makes: the batched engine's vector env, the seeded model, and the run's
    hyperparameters, env kwargs (:meth:`TrainConfig.resolve`) and step budget."""

    venv: gym.vector.VectorEnv
    model: object  # a dpr.rl.batched_ppo learner, or an SB3 model on the VecEnv adapter (learner="sb3")
    hyper: object
    env_kwargs: dict
    timesteps: int


def build_batched_run(config) -> BatchedRun:
    """The env and the model that ``dpr train --engine batched`` trains for ``config``: ``config.n_envs`` envs of the
    batched engine on ``config.device`` with its training kwargs, and the model seeded as every run of ``config``
    seeds it (the tensor PPO's learner, or SB3's model on the adapter). Bad kwargs, a device without CUDA or a swarm
    too large for memory fail here, before anything is written."""
    hyper, env_kwargs, timesteps = config.resolve()
    refuse_batched_only_kwargs(  # the model records them: it could run nowhere else
        env_kwargs,
        "a model is run and fine-tuned with its env kwargs on either engine: train in it as a training env kwarg "
        "(--training-env-kwarg {name}=...)",
    )
    venv = gym.make_vec(
        config.env_id,
        num_envs=config.n_envs,
        vectorization_mode="vector_entry_point",
        max_episode_steps=config.steps_per_episode,
        device=config.device,
        compile=config.compile,
        **config.training_kwargs(env_kwargs),
    )
    torch.manual_seed(config.seed)
    if config.learner == SB3_LEARNER:
        from dpr.rl.sb3_batched import BatchedSB3VecEnv

        adapter = BatchedSB3VecEnv(venv)
        adapter.seed(config.seed)
        model = build_model(hyper, adapter, config.seed, None, single_thread=False)
    else:
        model = build_learner(hyper, venv.unwrapped.template, config.seed)
    return BatchedRun(venv, model, hyper, env_kwargs, timesteps)


def train_batched(
    config,
    out: str | Path | None = None,
    *,
    show_progress: bool = True,
    resume: bool = False,
    snapshot_seconds: float | None = None,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
):
    """Train ``config`` (a :class:`dpr.rl.train.TrainConfig` with ``engine="batched"``) on ``config.n_envs`` envs
    of the batched engine (module docstring); a :class:`TrainResult`. ``snapshot_seconds``: between snapshots
    (default :data:`dpr.rl.resume.SNAPSHOT_SECONDS`; 0: after every update)."""
    if resume:
        _check_resume(config, out)
    venv, model, hyper, env_kwargs, timesteps = build_batched_run(config)  # refusals here leave nothing behind
    run_dir = Path(out) if resume else prepare_run_dir(out, config)
    config_path = run_dir / "config.yaml"
    record = yaml.safe_load(config_path.read_text()) if resume else _run_record(config, hyper, env_kwargs, timesteps)
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    again = " (resumed)" if resume else ""
    compiled = ", compiled: the first steps compile for seconds, minutes on a bare machine" if config.compile else ""
    log(
        f"dpr train: {config.algo} on the batched engine ({config.device}, {config.n_envs} envs, {config.learner} "
        f"learner{compiled}), {config.env_id} {env_kwargs}{again}"
    )
    info = ModelInfo(
        config.algo, config.env_id, env_kwargs, config.steps_per_episode, architecture=model_architecture(hyper)
    )
    started = time.perf_counter()
    with tqdm(total=timesteps, desc=f"train ppo {config.env_id}", unit="step", disable=not show_progress) as bar:
        history, interrupted = _learn(config, model, venv, timesteps, bar, (run_dir, resume, snapshot_seconds, info))
    seconds = time.perf_counter() - started
    venv.close()
    model_path = save_model(model, run_dir / "model.zip", info)
    (run_dir / "progress.yaml").write_text(yaml.safe_dump(history, sort_keys=False))
    made = int(model.num_timesteps)
    record.update(seconds=round(seconds, 1), timesteps_done=made, env_steps_per_second=round(made / seconds, 1))
    record["finished" if not interrupted else "interrupted"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    config_path.write_text(yaml.safe_dump(record, sort_keys=False))
    if not interrupted:
        resume_state.drop_snapshot(run_dir)
    log(f"dpr train: wrote {model_path} ({made} steps in {seconds:.0f} s, {made / seconds:,.0f} env steps/s)")
    return TrainResult(run_dir, model_path, config_path, None, timesteps, seconds, interrupted)


def _learn(config, model, venv, timesteps: int, bar, saving: tuple) -> tuple[list, bool]:
    """Run the learner; its statistics, and whether Ctrl-C stopped it. ``saving``: (run folder, whether to resume
    from its snapshot, seconds between snapshots, the ModelInfo its checkpoints carry). Either learner writes
    ``checkpoints/model_<steps>_steps.zip`` once its steps pass each of the :data:`dpr.rl.train.CHECKPOINTS` evenly
    spaced points of the run, as pymunk runs do."""
    run_dir, resume, every, info = saving
    checkpoint = _checkpointer(model, run_dir, info, timesteps)
    if config.learner == SB3_LEARNER:
        try:
            with unchecked_distributions():  # (the tensor loop, learn(), turns them off itself)
                model.learn(total_timesteps=timesteps, callback=_sb3_progress(bar, checkpoint))
        except KeyboardInterrupt:
            return [], True
        return [], False
    every = resume_state.SNAPSHOT_SECONDS if every is None else every
    env = venv.unwrapped
    start = resume_batched(run_dir, model, env) if resume else None
    kept = {"history": [] if start is None else start.history, "at": time.monotonic()}

    def on_update(loop) -> None:
        kept["history"] = loop.history
        checkpoint(loop.history[-2]["steps"] if len(loop.history) > 1 else 0, loop.history[-1]["steps"])
        if time.monotonic() - kept["at"] >= every:
            save_batched_snapshot(run_dir, model, env, loop)
            kept["at"] = time.monotonic()

    try:
        trained = learn(model, env, timesteps, config.seed, bar, start, on_update, compile=config.compile)
        return trained, False
    except KeyboardInterrupt:
        return list(kept["history"]), True


def _checkpointer(model, run_dir: Path, info: ModelInfo, timesteps: int) -> Callable[[int, int], None]:
    """``checkpoint(before, steps)``: saves ``model`` as ``checkpoints/model_<steps>_steps.zip`` when going from
    ``before`` to ``steps`` env steps passed one of the run's evenly spaced checkpoint points."""
    spacing = max(checkpoint_spacing(timesteps), 1)

    def checkpoint(before: int, steps: int) -> None:
        if steps // spacing > before // spacing:
            save_model(model, run_dir / "checkpoints" / f"model_{steps}_steps.zip", info)

    return checkpoint


def _sb3_progress(bar, checkpoint: Callable[[int, int], None]):
    """An SB3 callback moving ``bar`` by the steps of all envs and writing the run's checkpoints."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Progress(BaseCallback):
        def _on_step(self) -> bool:
            envs = self.training_env.num_envs
            bar.update(envs)
            checkpoint(self.num_timesteps - envs, self.num_timesteps)
            return True

    return Progress()

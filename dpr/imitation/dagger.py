"""DAgger: behaviour cloning with corrective labels from an expert that can label any state.

A clone trained on demonstrations alone drifts, in closed loop, into states the demonstrator never visited and
has no label for; its errors compound. Each DAgger round rolls the current clone out (it drives the env), asks
the expert what it would have done in every state the clone visited (``dpr collect --label-policy``), records
that as a new LeRobot dataset, and clones again on the demonstrations plus every round's data. The expert must
be a function of the observation, as ``wave-markov`` is on an env with ``obs_last_action=True``.

A run folder holds ``round-0`` (plain BC on the demonstrations), ``data-1`` .. ``data-K`` (the rounds' datasets),
``round-1`` .. ``round-K`` (each a :func:`behaviour_clone` run folder) and ``model.zip`` (the last round's model).
"""

from __future__ import annotations

import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dpr import runs
from dpr.checks import ParameterError
from dpr.datasets import features
from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import MAX_EPISODE_STEPS
from dpr.envs.particle_env import split_swarm_kwargs
from dpr.imitation.bc import BCResult, behaviour_clone, dataset_env
from dpr.imitation.config import CloneConfig, DaggerConfig
from dpr.policies.registry import make_policy
from dpr.policies.sb3 import FINETUNE_ALGOS

__all__ = ["DaggerResult", "dagger"]


@dataclass(frozen=True)
class DaggerResult:
    run_dir: Path
    model_path: Path
    rounds: list[BCResult]
    datasets: list[Path]


def check_demonstrations(
    demos: list[Path], env_id: str, config: DaggerConfig, requested: dict[str, Any]
) -> tuple[dict[str, Any], dict[str, Any], int]:
    """The swarm kwargs, the other env kwargs and the episode length the demonstrations were recorded with, which
    the DAgger rounds record with too. A ValueError when the DAgger seeds overlap the demonstrations' or the expert
    cannot label this env's observations."""
    readers = [LeRobotReader(path) for path in demos]
    env_kwargs, steps = dataset_env(readers[0], env_id, requested)
    demo_seeds = {int(meta[features.SEED]) for reader in readers for meta in reader.episodes if features.SEED in meta}
    dagger_seeds = set(config.seeds)
    if demo_seeds & dagger_seeds:
        raise ParameterError(
            "first_seed",
            f"DAgger seeds {min(dagger_seeds)}-{max(dagger_seeds)} overlap the "
            "demonstrations' seeds; choose seeds the dataset does not hold",
        )
    swarm, env_kwargs = split_swarm_kwargs(env_kwargs)
    steps = steps or MAX_EPISODE_STEPS
    probe = CollectSpec(env_id, policy=config.expert, steps=steps, env_kwargs=env_kwargs, **swarm).make_env()
    try:  # an expert that cannot label this env's observations (e.g. wave-markov without obs_last_action)
        make_policy(config.expert, probe)
    finally:
        probe.close()
    return swarm, env_kwargs, steps


def dagger(
    dataset_dirs: str | Path | list[str | Path],
    env_id: str,
    out: str | Path,
    config: DaggerConfig | None = None,
    clone: CloneConfig | None = None,
    *,
    show_progress: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
) -> DaggerResult:
    """Clone the demonstrations at ``dataset_dirs`` (one folder or several), then run ``config.rounds`` DAgger
    rounds of ``config.episodes_per_round`` episodes each (seeds from ``config.first_seed``, round after round),
    into the new folder ``out``. Every round clones as ``clone`` says (:func:`behaviour_clone`: algo, epochs, lr,
    seed...). Bad input raises ValueError first."""
    config = DaggerConfig() if config is None else config
    clone = CloneConfig() if clone is None else clone
    if clone.algo not in FINETUNE_ALGOS:
        raise ParameterError(
            "algo",
            f"DAgger clones into an actor-critic (one of {FINETUNE_ALGOS}), not {clone.algo!r}: "
            "a DQN clone acts in Discrete(2^N), not in the demonstrations' MultiBinary env it would "
            "have to drive",
        )
    runs.check_new_folder(out)
    out = Path(out)
    demos = [Path(dataset_dirs)] if isinstance(dataset_dirs, (str, Path)) else [Path(d) for d in dataset_dirs]
    swarm, env_kwargs, steps = check_demonstrations(demos, env_id, config, clone.env_kwargs)

    out.mkdir(parents=True, exist_ok=True)
    datasets = list(demos)

    def clone_round(index: int) -> BCResult:
        return behaviour_clone(
            datasets, env_id, clone, out=out / f"round-{index}", show_progress=show_progress, log=log
        )

    results = [clone_round(0)]
    for round_index in range(1, config.rounds + 1):
        learner = results[-1].model_path
        data = out / f"data-{round_index}"
        log(
            f"dpr bc: DAgger round {round_index}/{config.rounds}: {config.episodes_per_round} episodes of {learner} "
            f"labelled by {config.expert} -> {data}"
        )
        spec = CollectSpec(
            env_id, policy=str(learner), steps=steps, env_kwargs=env_kwargs, label_policy=config.expert, **swarm
        )
        seed = config.round_seed(round_index)
        summary = collect(data, spec, config.episodes_per_round, seed=seed, workers=RolloutWorkers(config.workers))
        if summary.interrupted:
            raise KeyboardInterrupt
        datasets.append(data)
        results.append(clone_round(round_index))
    model_path = out / "model.zip"
    shutil.copyfile(results[-1].model_path, model_path)
    return DaggerResult(out, model_path, results, datasets)

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
from dpr.checks import ParameterError, check_int
from dpr.datasets import features
from dpr.datasets.collect import CollectSpec, RolloutWorkers, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs import MAX_EPISODE_STEPS
from dpr.envs.particle_env import split_swarm_kwargs
from dpr.imitation.bc import BCResult, behaviour_clone, dataset_env
from dpr.policies.registry import WAVE_MARKOV, check_policy_name, make_policy
from dpr.policies.sb3 import DEFAULT_ALGO, FINETUNE_ALGOS

__all__ = ["DaggerResult", "dagger"]


@dataclass(frozen=True)
class DaggerResult:
    run_dir: Path
    model_path: Path
    rounds: list[BCResult]
    datasets: list[Path]


def dagger(
    dataset_dirs: str | Path | list[str | Path],
    env_id: str,
    out: str | Path,
    *,
    expert: str = WAVE_MARKOV,
    rounds: int = 2,
    episodes_per_round: int = 10,
    first_seed: int = 50_000,
    workers: int = 1,
    show_progress: bool = False,
    log: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
    **bc_kwargs: Any,
) -> DaggerResult:
    """Clone the demonstrations at ``dataset_dirs`` (one folder or several), then run ``rounds`` DAgger rounds
    of ``episodes_per_round`` episodes each (seeds from ``first_seed``, round after round), into the new
    folder ``out``. ``bc_kwargs`` go to every :func:`behaviour_clone` (algo, epochs, lr, seed...). Bad input
    raises ValueError first."""
    check_int("rounds", rounds, 0)
    check_int("episodes_per_round", episodes_per_round, 1)
    check_int("first_seed", first_seed, 0)
    check_policy_name(expert)
    algo = bc_kwargs.get("algo", DEFAULT_ALGO)
    if algo not in FINETUNE_ALGOS:
        raise ParameterError(
            "algo",
            f"DAgger clones into an actor-critic (one of {FINETUNE_ALGOS}), not {algo!r}: "
            "a DQN clone acts in Discrete(2^N), not in the demonstrations' MultiBinary env it would "
            "have to drive",
        )
    runs.check_new_folder(out)
    out = Path(out)
    demos = [Path(dataset_dirs)] if isinstance(dataset_dirs, (str, Path)) else [Path(d) for d in dataset_dirs]
    readers = [LeRobotReader(path) for path in demos]
    env_kwargs, steps = dataset_env(readers[0], env_id, bc_kwargs.get("env_kwargs"))
    demo_seeds = {int(meta[features.SEED]) for reader in readers for meta in reader.episodes if features.SEED in meta}
    dagger_seeds = set(range(first_seed, first_seed + rounds * episodes_per_round))
    if demo_seeds & dagger_seeds:
        raise ParameterError(
            "first_seed",
            f"DAgger seeds {min(dagger_seeds)}-{max(dagger_seeds)} overlap the "
            "demonstrations' seeds; choose seeds the dataset does not hold",
        )
    swarm, env_kwargs = split_swarm_kwargs(env_kwargs)
    steps = steps or MAX_EPISODE_STEPS
    spec = CollectSpec(env_id, policy=expert, steps=steps, env_kwargs=env_kwargs, **swarm)
    probe = spec.make_env()
    try:  # an expert that cannot label this env's observations (e.g. wave-markov without obs_last_action)
        make_policy(expert, probe)
    finally:
        probe.close()

    out.mkdir(parents=True, exist_ok=True)
    datasets = list(demos)
    results = [
        behaviour_clone(datasets, env_id, out=out / "round-0", show_progress=show_progress, log=log, **bc_kwargs)
    ]
    for round_index in range(1, rounds + 1):
        learner = results[-1].model_path
        data = out / f"data-{round_index}"
        log(
            f"dpr bc: DAgger round {round_index}/{rounds}: {episodes_per_round} episodes of {learner} labelled by "
            f"{expert} -> {data}"
        )
        spec = CollectSpec(
            env_id, policy=str(learner), steps=steps, env_kwargs=env_kwargs, label_policy=expert, **swarm
        )
        round_first_seed = first_seed + (round_index - 1) * episodes_per_round
        summary = collect(data, spec, episodes_per_round, seed=round_first_seed, workers=RolloutWorkers(workers))
        if summary.interrupted:
            raise KeyboardInterrupt
        datasets.append(data)
        results.append(
            behaviour_clone(
                datasets, env_id, out=out / f"round-{round_index}", show_progress=show_progress, log=log, **bc_kwargs
            )
        )
    model_path = out / "model.zip"
    shutil.copyfile(results[-1].model_path, model_path)
    return DaggerResult(out, model_path, results, datasets)

"""How many steps a training run makes, against the steps it is asked for.

SB3 collects experience in whole rollouts: PPO and A2C ``n_steps`` steps of each of the ``n_envs`` envs at a time
(DQN ``train_freq`` steps of each), and ``learn(total_timesteps)`` ends after the rollout that reaches
``total_timesteps``, so a budget that is not a whole number of rollouts is rounded up; so is the critic warm-up of
a fine-tuning run, a ``learn`` call of its own.

:func:`fit_budget` keeps SB3's rule where the training budget holds at least one rollout: the run makes
``total_timesteps`` rounded up to whole rollouts, and the log and ``config.yaml`` say how many steps that is. A PPO
or A2C budget smaller than one rollout would otherwise run a whole one (``--timesteps 200`` with rollouts of 512
steps ran 512): such a run gets rollouts short enough that its warm-up and its training each run whole ones and no
more steps than asked, ``n_steps`` = the smaller of the two budgets // ``n_envs`` (PPO's ``batch_size`` the
largest, up to its own, that splits a rollout into whole mini-batches), and its log names the values. Only a
budget under one step of every env (or under two steps for PPO, which needs two per rollout) runs more: one
rollout of that size.
"""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass
from typing import Any

from dpr.limits import (
    MAX_EPISODES,
    MAX_MODEL_SEED,
    MAX_N_ENVS,
    MAX_N_ROBOTS,
    MAX_STEPS_PER_EPISODE,
    MAX_TIMESTEPS,
    WORKER_BYTES,
    check_memory,
    env_bytes,
)
from dpr.policies.hyperparams import Hyperparams
from dpr.policies.model_file import PPO
from dpr.policies.sb3 import algo_class

# The bounds of a training run's counts (dpr.rl.train.TrainConfig): name -> (minimum, maximum).
TRAIN_COUNT_BOUNDS = {
    "n_robots": (1, MAX_N_ROBOTS),
    "n_envs": (1, MAX_N_ENVS),
    "steps_per_episode": (1, MAX_STEPS_PER_EPISODE),
    "timesteps": (1, MAX_TIMESTEPS),
    "eval_episodes": (0, MAX_EPISODES),
    "seed": (0, MAX_MODEL_SEED),
    "critic_warmup": (0, MAX_TIMESTEPS),
}


def check_training_memory(n_envs: int, n_robots: int, robot_model: str, engine: str, device: str) -> None:
    """A ParameterError about n_envs, saying the estimate, when the envs of a training run cannot fit this machine's
    memory (on the pymunk engine each of several envs is a process of its own; on the batched engine its world's
    tensors, against the device's memory), or about device when this machine lacks it."""
    if engine == "pymunk":
        per_env = env_bytes(n_robots, robot_model) + (WORKER_BYTES if n_envs > 1 else 0)
        what = f"{n_envs} envs of {n_robots} robots" + (" (a process each)" if n_envs > 1 else "")
        check_memory("n_envs", what, n_envs * per_env)
    else:
        from dpr.sim.batched import checked_size

        checked_size(n_envs, n_robots, device, name="n_envs")


ON_POLICY = ("ppo", "a2c")


@dataclass(frozen=True)
class Budget:
    """What a run's two ``learn`` calls are given and what they make, in env steps."""

    rollout: int  # env steps per collection: n_steps x n_envs (DQN's train_freq x n_envs); 0 where unknown
    warmup_asked: int
    training_asked: int
    warmup_learn: int  # total_timesteps of the critic warm-up's learn call
    training_learn: int  # ... and of the training's
    warmup_runs: int  # the steps each makes
    training_runs: int
    note: str | None  # the log line saying how and why the steps differ from those asked (None: they do not)

    def record(self) -> dict[str, Any]:
        """The run's ``steps`` entry in ``config.yaml``."""
        return {
            "rollout": self.rollout,
            "critic_warmup": self.warmup_runs,
            "training": self.training_runs,
            "note": self.note,
        }


def _default(algo: str, name: str):
    return inspect.signature(algo_class(algo)).parameters[name].default


def _whole(steps: int, rollout: int) -> int:
    """The steps SB3 makes for a ``learn`` call of ``steps``: whole rollouts, rounded up."""
    return -(-steps // rollout) * rollout if rollout and steps else steps


def fit_budget(
    hyper: Hyperparams, n_envs: int, timesteps: int, critic_warmup: int, command: str
) -> tuple[Hyperparams, Budget]:
    """The hyperparameters a run of ``timesteps`` training steps after ``critic_warmup`` warm-up steps on
    ``n_envs`` envs trains with (``hyper``, or shorter rollouts: see the module's docstring) and its
    :class:`Budget`."""
    kwargs = hyper.algo_kwargs
    size = kwargs.get("n_steps" if hyper.algo in ON_POLICY else "train_freq")
    if size is None:
        size = _default(hyper.algo, "n_steps" if hyper.algo in ON_POLICY else "train_freq")
    n_steps, rollout = None, 0  # a train_freq of episodes makes as many steps as the episodes last
    if isinstance(size, int) and not isinstance(size, bool) and size > 0:  # (SB3 refuses other values, later)
        rollout = size * n_envs
        n_steps = size if hyper.algo in ON_POLICY else None
    if n_steps is None or timesteps >= rollout:
        budget = Budget(
            rollout,
            critic_warmup,
            timesteps,
            critic_warmup,
            timesteps,
            _whole(critic_warmup, rollout),
            _whole(timesteps, rollout),
            None,
        )
        return hyper, dataclasses.replace(budget, note=_rounding_note(budget, hyper, n_envs, command))
    smallest = min(timesteps, critic_warmup) if critic_warmup else timesteps
    shorter = max(smallest // n_envs, 2 if hyper.algo == PPO else 1)
    changed = {"n_steps": shorter}
    batch_size = kwargs.get("batch_size", _default(PPO, "batch_size")) if hyper.algo == PPO else None
    if isinstance(batch_size, int) and batch_size > 1:  # (SB3 refuses other values)
        # the largest that splits a rollout into whole mini-batches, as SB3 recommends (else the yaml's)
        sizes = range(2, min(batch_size, shorter * n_envs) + 1)
        fits = max((size for size in sizes if shorter * n_envs % size == 0), default=batch_size)
        if fits != batch_size:
            changed["batch_size"] = fits
    fitted = dataclasses.replace(hyper, algo_kwargs={**kwargs, **changed})
    rollout = shorter * n_envs
    warmup, training = (max(steps // rollout, 1) * rollout if steps else 0 for steps in (critic_warmup, timesteps))
    phases = f"{training} training steps" + (f" after {warmup} critic warm-up steps" if critic_warmup else "")
    asked = f"{timesteps}" + (f" and {critic_warmup}" if critic_warmup else "")
    settings = " ".join(f"{name}={value}" for name, value in changed.items())
    note = (
        f"dpr {command}: {timesteps} steps are fewer than one rollout of n_steps {n_steps} x {n_envs} envs; "
        f"this run collects rollouts of {settings} ({rollout} steps) and makes {phases} ({asked} asked)"
    )
    return fitted, Budget(rollout, critic_warmup, timesteps, warmup, training, warmup, training, note)


def _rounding_note(budget: Budget, hyper: Hyperparams, n_envs: int, command: str) -> str | None:
    """The log line of a run whose budgets SB3 rounds up to whole rollouts (None: they are whole already)."""
    phases = [
        f"{runs} {name} steps for the {asked} asked"
        for name, runs, asked in (
            ("critic warm-up", budget.warmup_runs, budget.warmup_asked),
            ("training", budget.training_runs, budget.training_asked),
        )
        if runs != asked
    ]
    if not phases:
        return None
    size = "n_steps" if hyper.algo in ON_POLICY else "train_freq"
    return (
        f"dpr {command}: {hyper.algo} collects whole rollouts of {size} x {n_envs} envs = {budget.rollout} steps, "
        f"so this run makes {' and '.join(phases)}"
    )

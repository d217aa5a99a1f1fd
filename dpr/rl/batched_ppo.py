"""PPO on the batched disk engine with rollouts, advantages and updates on the engine's device.

SB3's ``PPO.learn`` copies every step's actions to numpy and loops over done flags in Python; at thousands of
swarms per call that bookkeeping costs more than the physics. This module keeps the loop on tensors, in the shape of
CleanRL's ``ppo_continuous_action_isaacgym.py``: ``n_steps`` steps of all ``num_envs`` envs, generalised advantage
estimates over them, then ``n_epochs`` passes of shuffled mini-batches with PPO's clipped objective.

The learner is an ordinary SB3 PPO model (built by :func:`dpr.policies.sb3.build_model` from a hyperparameter entry,
``SwarmPolicy`` or ``MlpPolicy``): this loop calls its policy's ``forward``, ``evaluate_actions`` and
``predict_values`` and its optimiser, and saves it with :func:`dpr.policies.sb3.save_model`. So the file is the
same safe format as ``dpr train``'s (:mod:`dpr.rl.batched_train` writes the run): it runs on either engine, and
``dpr finetune --from`` continues it on pymunk.

The env is a :class:`TensorEnv`: the batched vector env's tensor interface, which resets an env in the step that
ends its episode and hands back the observation it ended on, so that a time-limit truncation bootstraps from it
(as SB3 does, ``reward += gamma * V(final observation)``).
"""

from __future__ import annotations

import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
from torch import nn

from dpr.checks import ParameterError, check_int
from dpr.policies.distributions import unchecked_distributions
from dpr.policies.hyperparams import Hyperparams
from dpr.policies.model_file import PPO
from dpr.policies.sb3 import build_model

# what each update reports, the means of minibatch_loss's terms over its mini-batches
TERMS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")
# torch.compile's settings for the loss. Inductor's CPU code takes tanh from Sleef's 1-ULP routine, several times
# slower than eager torch's; its exp form (within 2e-7 of tanh) makes a compiled update of the swarm actor, whose
# layers are tanh, about 15% faster. GPU code does not read it.
LOSS_COMPILE_OPTIONS = {"cpp.use_decompose_tanh": True}


class TensorEnv(Protocol):
    """What the loop needs of a batched env: tensors in, tensors out, on ``device``."""

    num_envs: int
    device: torch.device

    def reset_tensors(self, seed: int | None = None) -> torch.Tensor:
        """Reset every env; the observations [K, D]."""

    def step_tensors(self, actions: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """One step of every env: ``(observation, reward, terminated, truncated, final_observation)``, where an env
        whose episode ended is already reset in ``observation`` and ``final_observation`` holds where it ended."""


@dataclass(frozen=True)
class RolloutSettings:
    """The PPO values the loop reads from a hyperparameter entry (SB3's names and defaults)."""

    n_steps: int
    batch_size: int
    n_epochs: int
    gamma: float
    gae_lambda: float
    ent_coef: float
    vf_coef: float
    max_grad_norm: float
    target_kl: float | None
    normalize_advantage: bool

    @classmethod
    def of(cls, model) -> RolloutSettings:
        return cls(
            n_steps=model.n_steps,
            batch_size=model.batch_size,
            n_epochs=model.n_epochs,
            gamma=model.gamma,
            gae_lambda=model.gae_lambda,
            ent_coef=float(model.ent_coef),
            vf_coef=model.vf_coef,
            max_grad_norm=model.max_grad_norm,
            target_kl=model.target_kl,
            normalize_advantage=model.normalize_advantage,
        )


@dataclass
class Rollout:
    """``n_steps`` x ``num_envs`` transitions, as tensors [T, K, ...] on the env's device."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    values: torch.Tensor
    rewards: torch.Tensor
    dones: torch.Tensor  # the episode ended at this step (terminated or truncated)
    advantages: torch.Tensor | None = None
    returns: torch.Tensor | None = None

    @classmethod
    def empty(cls, steps: int, envs: int, observation_size: int, action_size: int, device) -> Rollout:
        zeros = lambda *shape: torch.zeros(shape, dtype=torch.float32, device=device)  # noqa: E731
        return cls(
            zeros(steps, envs, observation_size),
            zeros(steps, envs, action_size),
            zeros(steps, envs),
            zeros(steps, envs),
            zeros(steps, envs),
            zeros(steps, envs),
        )


def build_learner(hyper: Hyperparams, template_env, seed: int):
    """The SB3 PPO model ``hyper`` describes, built on one single env of the same spaces (``template_env``, whose
    attributes the swarm actor reads), its weights on the CPU as every model file's are."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    if hyper.algo != PPO:
        raise ParameterError("algo", f"the batched engine trains {PPO} only, got {hyper.algo!r}")
    with warnings.catch_warnings():  # SB3 sizes its own buffer for one env; this loop has its own
        warnings.filterwarnings("ignore", message="You have specified a mini-batch size")
        return build_model(hyper, DummyVecEnv([lambda: template_env]), seed, None, single_thread=False)


def collect_rollout(policy, env: TensorEnv, observation: torch.Tensor, settings: RolloutSettings, rollout: Rollout):
    """Fill ``rollout`` with ``n_steps`` steps of every env from ``observation``; the observation after them."""
    for step in range(settings.n_steps):
        with torch.no_grad():
            actions, values, log_probs = policy(observation)
        next_observation, reward, terminated, truncated, final_observation = env.step_tensors(actions)
        if truncated.any():  # a time limit is not the task's end: bootstrap from where the episode stopped
            with torch.no_grad():
                final_values = policy.predict_values(final_observation[truncated]).flatten()
            reward = reward.clone()
            reward[truncated] += settings.gamma * final_values
        rollout.observations[step] = observation
        rollout.actions[step] = actions.float()
        rollout.log_probs[step] = log_probs
        rollout.values[step] = values.flatten()
        rollout.rewards[step] = reward
        rollout.dones[step] = (terminated | truncated).float()
        observation = next_observation
    return observation


def estimate_advantages(policy, rollout: Rollout, last_observation: torch.Tensor, settings: RolloutSettings) -> None:
    """Generalised advantage estimates and returns (Schulman et al. 2016), backwards over the rollout."""
    with torch.no_grad():
        next_value = policy.predict_values(last_observation).flatten()
    advantages = torch.zeros_like(rollout.rewards)
    running = torch.zeros_like(next_value)
    for step in reversed(range(rollout.rewards.shape[0])):
        carries = 1.0 - rollout.dones[step]  # nothing flows back across an episode's end
        delta = rollout.rewards[step] + settings.gamma * next_value * carries - rollout.values[step]
        running = delta + settings.gamma * settings.gae_lambda * carries * running
        advantages[step] = running
        next_value = rollout.values[step]
    rollout.advantages = advantages
    rollout.returns = advantages + rollout.values


def minibatch_loss(policy, batch: tuple[torch.Tensor, ...], settings: RolloutSettings, clip_range: torch.Tensor):
    """PPO's clipped objective (SB3's losses) on one mini-batch ``(observations, actions, old log-probabilities,
    advantages, returns, *parts)``: the loss to minimise, and its terms as tensors. ``parts``, where the policy has
    them, are its ``observation_parts`` of the observations; ``clip_range`` is a tensor, so that a schedule's new
    value does not make ``torch.compile`` compile again."""
    observations, actions, old_log_probs, advantages, returns, *parts = batch
    if parts:
        values, log_probs, entropy = policy.evaluate_actions(observations, actions, parts=tuple(parts))
    else:
        values, log_probs, entropy = policy.evaluate_actions(observations, actions)
    if settings.normalize_advantage and advantages.shape[0] > 1:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    log_ratio = log_probs - old_log_probs
    ratio = torch.exp(log_ratio)
    policy_loss = -torch.min(advantages * ratio, advantages * ratio.clamp(1 - clip_range, 1 + clip_range)).mean()
    value_loss = nn.functional.mse_loss(returns, values.flatten())
    entropy_loss = -entropy.mean() if entropy is not None else log_probs.mean()
    loss = policy_loss + settings.ent_coef * entropy_loss + settings.vf_coef * value_loss
    with torch.no_grad():
        terms = {
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": -entropy_loss,
            "approx_kl": ((ratio - 1) - log_ratio).mean(),
            "clip_fraction": ((ratio - 1).abs() > clip_range).float().mean(),
        }
    return loss, terms


def update(model, rollout: Rollout, settings: RolloutSettings, clip_range: float, loss_of=minibatch_loss):
    """``n_epochs`` passes of PPO's clipped objective over shuffled mini-batches of ``rollout``; ``loss_of`` is
    :func:`minibatch_loss` or its compiled form."""
    policy = model.policy
    flat = lambda tensor: tensor.reshape(-1, *tensor.shape[2:])  # noqa: E731
    data = [flat(part) for part in (rollout.observations, rollout.actions, rollout.log_probs)]
    data += [flat(rollout.advantages), flat(rollout.returns)]
    if hasattr(policy, "observation_parts"):  # the swarm policy's split of its observations: once, not every epoch
        with torch.no_grad():
            data += policy.observation_parts(data[0])
    device = data[0].device
    clip = torch.tensor(clip_range, dtype=torch.float32, device=device)
    # the terms add up on the device, so that a GPU is not waited for at every mini-batch (only for the KL, where a
    # target_kl may stop the update)
    totals, batches = torch.zeros(len(TERMS), dtype=torch.float64, device=device), 0
    with fused_adam(policy.optimizer):
        for _ in range(settings.n_epochs):
            for index in torch.randperm(data[0].shape[0], device=device).split(settings.batch_size):
                loss, terms = loss_of(policy, tuple(part[index] for part in data), settings, clip)
                if settings.target_kl is not None and float(terms["approx_kl"]) > 1.5 * settings.target_kl:
                    return _means(totals, batches)  # SB3's early stop: the policy moved far enough this update
                policy.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(policy.parameters(), settings.max_grad_norm)
                policy.optimizer.step()
                batches += 1
                totals += torch.stack([terms[name].detach() for name in TERMS]).double()
    return _means(totals, batches)


@contextmanager
def fused_adam(optimizer):
    """Within: ``optimizer`` steps with torch's fused kernel where it is Adam on the CPU (one call for all the
    parameters instead of a dozen per parameter: about a third of the time; the same update but for rounding). Each
    parameter group's own setting is back after, so that the files saved between updates record the model's."""
    before = [group.get("fused") for group in optimizer.param_groups]
    on_cpu = all(p.device.type == "cpu" for group in optimizer.param_groups for p in group["params"])
    if isinstance(optimizer, torch.optim.Adam) and on_cpu:
        for group in optimizer.param_groups:
            group["fused"] = not group.get("foreach") and not group.get("differentiable")
    try:
        yield
    finally:
        for group, setting in zip(optimizer.param_groups, before):
            group["fused"] = setting


def _means(totals: torch.Tensor, batches: int) -> dict[str, float]:
    return dict(zip(TERMS, (totals / max(batches, 1)).tolist()))


@unchecked_distributions()
def learn(model, env: TensorEnv, timesteps: int, seed: int, progress=None, start=None, on_update=None, compile=False):
    """Train ``model`` (an SB3 PPO model; its policy and optimiser move to ``env.device`` for the run and back to the
    CPU) for at least ``timesteps`` env steps of all envs together, in whole rollouts of ``n_steps`` x ``num_envs``;
    the statistics of each update. ``model.num_timesteps`` counts the steps made. ``compile``: ``torch.compile`` the
    mini-batch loss, forward and backward (seconds of compiling at the first update).

    ``start`` (a :class:`dpr.rl.batched_resume.LoopState`) goes on from a stopped run's updates, observation and
    statistics instead of resetting the envs; ``on_update(state)`` is called with the loop's state after each
    update (where a run keeps its snapshots)."""
    from dpr.rl.batched_resume import LoopState

    check_int("timesteps", timesteps, 1)
    settings = RolloutSettings.of(model)
    policy = move_learner(model.policy, env.device)
    policy.set_training_mode(True)
    per_update = settings.n_steps * env.num_envs
    updates = -(-timesteps // per_update)
    if start is None:
        start = LoopState(0, env.reset_tensors(seed), [])
    observation, history = start.observation, list(start.history)
    action_size = int(np.prod(model.action_space.shape)) if model.action_space.shape else 1
    rollout = Rollout.empty(settings.n_steps, env.num_envs, observation.shape[1], action_size, env.device)
    if progress is not None and start.updates:
        progress.update(start.updates * per_update)
    loss_of = torch.compile(minibatch_loss, options=LOSS_COMPILE_OPTIONS) if compile else minibatch_loss
    try:
        for number in range(start.updates, updates):
            remaining = 1.0 - number / updates  # SB3's progress_remaining: the schedules' clock
            for group in policy.optimizer.param_groups:
                group["lr"] = model.lr_schedule(remaining)
            observation = collect_rollout(policy, env, observation, settings, rollout)
            estimate_advantages(policy, rollout, observation, settings)
            stats = update(model, rollout, settings, model.clip_range(remaining), loss_of)
            if not all(math.isfinite(value) for value in stats.values()):  # (torch's distributions no longer check)
                raise FloatingPointError(
                    f"PPO's update {number + 1} gave terms that are not numbers: {stats}; look for rewards or "
                    "observations that are not numbers, or lower the learning rate"
                )
            history.append({"steps": (number + 1) * per_update, "mean_reward": float(rollout.rewards.mean()), **stats})
            model.num_timesteps = (number + 1) * per_update
            if progress is not None:
                progress.update(per_update)
            if on_update is not None:
                on_update(LoopState(number + 1, observation, history))
    finally:  # (a Ctrl-C too: the model is saved as it is)
        move_learner(policy, "cpu")
    return history


def move_learner(policy, device):
    """``policy`` and its optimiser's state (Adam's moments of a resumed run) on ``device`` (or whatever else
    ``Module.to`` takes, a dtype): ``Module.to`` moves the parameters only, and Adam then refuses moments on another
    device. Reloading the optimiser's own state lets torch put each value beside its parameter, its step counter
    where Adam keeps it."""
    policy.to(device)
    policy.optimizer.load_state_dict(policy.optimizer.state_dict())
    return policy

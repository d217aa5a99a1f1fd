"""The batched PPO reads its tensors back to the host rarely: on a GPU each read waits for the device to finish. A CPU
cannot time that wait, but it can count the reads (a torch function mode sees every call that hands a tensor's
values to Python)."""

import dataclasses
from collections import Counter

import torch
from torch.overrides import TorchFunctionMode

import dpr  # noqa: F401
import dpr.rl.batched_ppo as batched_ppo
from dpr.policies.distributions import unchecked_distributions
from dpr.rl.batched_train import build_batched_run
from dpr.rl.train import TrainConfig

READS = {
    torch.Tensor.__bool__,
    torch.Tensor.__int__,
    torch.Tensor.__float__,
    torch.Tensor.item,
    torch.Tensor.tolist,
    torch.Tensor.cpu,
    torch.Tensor.numpy,
    torch.Tensor.nonzero,
    torch.nonzero,
}


class HostReads(TorchFunctionMode):
    """Counts, by name, the calls that read a tensor's values back to the host."""

    def __init__(self):
        super().__init__()
        self.counts = Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if func in READS:
            self.counts[func.__name__] += 1
        return func(*args, **(kwargs or {}))


def _learner(num_envs: int, action_repeat: int):
    config = TrainConfig(
        "ppo",
        "dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        n_envs=num_envs,
        preset="batched",
        engine="batched",
        steps_per_episode=50,
        training_env_kwargs={"action_repeat": action_repeat},
    )
    venv, model, *_ = build_batched_run(config)
    settings = dataclasses.replace(batched_ppo.RolloutSettings.of(model), n_steps=4, n_epochs=2, batch_size=8)
    return venv.unwrapped, model, settings


def test_an_update_reads_the_device_back_once_whatever_its_mini_batches():
    env, model, settings = _learner(num_envs=8, action_repeat=1)
    observation = env.reset_tensors(0)
    rollout = batched_ppo.Rollout.empty(4, 8, observation.shape[1], 4, "cpu")
    last = batched_ppo.collect_rollout(model.policy, env, observation, settings, rollout)
    batched_ppo.estimate_advantages(model.policy, rollout, last, settings)
    with unchecked_distributions(), HostReads() as reads:  # as learn() runs it
        stats = batched_ppo.update(model, rollout, settings, 0.2)
    assert reads.counts == Counter(tolist=1)  # the means, after 8 mini-batches (32 samples in 8s, twice)
    assert set(stats) == set(batched_ppo.TERMS)


def test_a_rollout_step_reads_the_device_back_once_a_physics_step_and_once_more():
    """Per env step: whether any env reached the goal inside the step (every physics step but the last), whether
    any ended (to draw new starts), whether any hit the time limit (to bootstrap it)."""
    env, model, settings = _learner(num_envs=8, action_repeat=3)
    observation = env.reset_tensors(0)
    rollout = batched_ppo.Rollout.empty(4, 8, observation.shape[1], 4, "cpu")
    with unchecked_distributions(), HostReads() as reads:
        batched_ppo.collect_rollout(model.policy, env, observation, settings, rollout)
    assert reads.counts == Counter(__bool__=4 * (3 - 1 + 1 + 1))

"""The behaviour-cloning loss and the dataset check it needs, shared by :mod:`dpr.imitation.bc` (cloning) and
:mod:`dpr.rl.anchor` (anchoring fine-tuning to the same demonstrations).

The loss is the negative log-likelihood of a recorded action under the policy's own action distribution
(MultiBinary -> one Bernoulli per robot), or for DQN the cross-entropy of the recorded action's index among the
2^N Q-values taken as logits.
"""

from __future__ import annotations

import gymnasium as gym
import torch

from dpr.checks import ParameterError
from dpr.datasets.features import ACTION, OBSERVATION
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs.particle_env import joint_action_bits

__all__ = ["batch_stats", "check_features"]


def _space_text(space: gym.Space) -> str:
    return f"Box(shape={space.shape})" if isinstance(space, gym.spaces.Box) else str(space)


def check_features(
    reader: LeRobotReader,
    observation_space: gym.Space,
    action_space: gym.Space,
    env_text: str,
    parameter: str = "dataset_dirs",
) -> None:
    """A :class:`ParameterError` about ``parameter`` (the caller's parameter that named the dataset) naming the
    dataset and both sides when the dataset's observation or action feature does not fit the spaces."""
    problems = []
    observation = reader.features.get(OBSERVATION)
    if (
        observation is None
        or not isinstance(observation_space, gym.spaces.Box)
        or tuple(observation.get("shape", ())) != observation_space.shape
    ):
        shape = None if observation is None else observation.get("shape")
        problems.append(
            f"{OBSERVATION} has shape {shape}, the env's observation space is {_space_text(observation_space)}"
        )
    action = reader.features.get(ACTION)
    if isinstance(action_space, gym.spaces.MultiBinary):
        n_robots = int(action_space.n)
    elif isinstance(action_space, gym.spaces.Discrete):  # DQN: the recorded bits become one integer
        n_robots = int(action_space.n).bit_length() - 1
    else:
        n_robots = None
        problems.append(f"the env's action space {_space_text(action_space)} is neither MultiBinary nor Discrete(2^N)")
    if n_robots is not None and (action is None or list(action.get("shape", ())) != [n_robots]):
        shape = None if action is None else action.get("shape")
        problems.append(
            f"{ACTION} has shape {shape}, expected [{n_robots}] (one 0/1 per robot) for the env's "
            f"action space {action_space}"
        )
    if problems:
        raise ParameterError(parameter, f"{reader.root} does not fit {env_text}: " + "; ".join(problems))


def batch_stats(policy, observation: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-frame negative log-likelihood [B] and per-robot correctness of the deterministic action [B, N]."""
    if hasattr(policy, "q_net"):  # DQN: Q-values as the logits of a softmax over the 2^N joint actions
        bits = torch.from_numpy(joint_action_bits(action.shape[1]))
        logits = policy.q_net(observation)
        nll = torch.nn.functional.cross_entropy(logits, (action.long() * bits).sum(1), reduction="none")
        chosen = logits.argmax(dim=1, keepdim=True)
        correct = ((chosen & bits) > 0).to(action.dtype) == action
        return nll, correct
    distribution = policy.get_distribution(observation)
    nll = -distribution.log_prob(action)  # Bernoulli log-probs summed over robots
    correct = distribution.mode() == action
    return nll, correct

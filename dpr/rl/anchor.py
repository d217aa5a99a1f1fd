"""Demonstration anchoring for fine-tuning: keep a cloned policy close to its demonstrations while RL improves it.

After every PPO/A2C update, the anchor takes ``ANCHOR_BATCHES`` gradient steps of the behaviour-cloning loss
(the demonstrated action's negative log-likelihood) on random demonstration frames, with the model's own
optimizer, scaled by ``weight * decay ** k`` at the ``k``-th update. This is the demonstration term of DAPG
(Rajeswaran et al., 2018), taken as its own step after each policy-gradient update instead of inside the same
loss, so SB3's update code stays untouched. Early on the anchor holds the policy at the clone, where the
clone is good and the critic still poor; as the weight decays, the returns take over.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from dpr.checks import ParameterError
from dpr.datasets.features import ACTION, OBSERVATION
from dpr.datasets.lerobot import LeRobotReader
from dpr.imitation.loss import batch_stats, check_features
from dpr.policies.sb3 import actor_parameters

ANCHOR_BATCHES = 8  # gradient steps per update: a few, so the anchor pulls rather than re-clones
ANCHOR_BATCH_SIZE = 256
MAX_GRAD_NORM = 0.5  # as PPO's and A2C's own updates
ANCHOR_PARAMETER = "anchor_datasets"  # the TrainConfig field the demonstrations come from


@dataclass(frozen=True)
class Demonstrations:
    """Every frame of one or more datasets, as the tensors the policy takes."""

    observation: torch.Tensor  # [F, D] float32
    action: torch.Tensor  # [F, N] float32 0/1
    sources: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.observation)

    def record(self, weight: float, decay: float) -> dict:
        """What a run's config.yaml says about its anchor."""
        return {
            "datasets": list(self.sources),
            "frames": len(self),
            "weight": weight,
            "decay": decay,
            "batches_per_update": ANCHOR_BATCHES,
            "batch_size": ANCHOR_BATCH_SIZE,
        }


def load_demonstrations(
    dataset_dirs: list[str | Path], observation_space: gym.Space, action_space: gym.Space, env_text: str
) -> Demonstrations:
    """Read every frame of the datasets at ``dataset_dirs`` (a :class:`ParameterError` about ``anchor_datasets``,
    the field of :class:`dpr.rl.train.TrainConfig` they come from, naming a dataset whose features do not fit the
    spaces; DatasetError for one that is not a dataset)."""
    if not isinstance(action_space, gym.spaces.MultiBinary):
        raise ParameterError(
            ANCHOR_PARAMETER, f"the demonstration loss needs a MultiBinary action space, not {action_space}"
        )
    if not dataset_dirs:
        raise ParameterError(ANCHOR_PARAMETER, "give at least one dataset")
    observations, actions = [], []
    for path in dataset_dirs:
        reader = LeRobotReader(path)
        check_features(reader, observation_space, action_space, env_text, parameter=ANCHOR_PARAMETER)
        frames = reader.frame_range(0, reader.num_frames, [OBSERVATION, ACTION])
        observations.append(np.asarray(frames[OBSERVATION], dtype=np.float32))
        actions.append(np.asarray(frames[ACTION], dtype=np.float32))
    return Demonstrations(
        torch.from_numpy(np.concatenate(observations)),
        torch.from_numpy(np.concatenate(actions)),
        tuple(str(Path(p).resolve()) for p in dataset_dirs),
    )


def demonstration_anchor(demonstrations: Demonstrations, weight: float, decay: float, seed: int):
    """The SB3 callback that anchors every update (see the module docstring); it logs ``anchor/weight`` and
    ``anchor/nll`` (the mean NLL of its last batches) to the model's logger."""
    from stable_baselines3.common.callbacks import BaseCallback

    class DemonstrationAnchor(BaseCallback):
        def _on_training_start(self) -> None:
            self.generator = torch.Generator().manual_seed(seed)
            self.updates = 0
            self.first_rollout = True

        def _on_rollout_start(self) -> None:
            # A rollout starts right after an update (except the first one): anchor what that update did.
            if self.first_rollout:
                self.first_rollout = False
                return
            self.anchor()

        def _on_training_end(self) -> None:
            self.anchor()  # the last update has no rollout after it

        def anchor(self) -> None:
            scale = weight * decay**self.updates
            self.updates += 1
            policy = self.model.policy
            policy.set_training_mode(True)
            parameters = actor_parameters(policy)
            total = 0.0
            for _ in range(ANCHOR_BATCHES):
                index = torch.randint(len(demonstrations), (ANCHOR_BATCH_SIZE,), generator=self.generator)
                nll = batch_stats(policy, demonstrations.observation[index], demonstrations.action[index])[0].mean()
                policy.optimizer.zero_grad()
                (scale * nll).backward()
                torch.nn.utils.clip_grad_norm_(parameters, MAX_GRAD_NORM)
                policy.optimizer.step()
                total += float(nll.detach())
            policy.set_training_mode(False)
            self.logger.record("anchor/weight", scale)
            self.logger.record("anchor/nll", total / ANCHOR_BATCHES)

        def _on_step(self) -> bool:
            return True

    return DemonstrationAnchor()

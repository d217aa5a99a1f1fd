"""The batched engine as a stable-baselines3 ``VecEnv``: any SB3 algorithm trains on K swarms stepped in one call.

:class:`BatchedSB3VecEnv` wraps a :class:`dpr.envs.batched.BatchedSwarmVectorEnv` (what
``gymnasium.make_vec(id, num_envs=K, vectorization_mode="vector_entry_point", robot_model="disk")`` returns) and
speaks SB3's conventions: numpy in and out, an env whose episode ended is reset in the same step, its last
observation in ``infos[i]["terminal_observation"]``, ``infos[i]["TimeLimit.truncated"]`` for a time limit (or a
physics error), and ``infos[i]["episode"]`` (return, length, seconds) as SB3's ``Monitor`` writes it, so that
``model.ep_info_buffer`` fills. Seeds follow SB3's: ``seed(s)`` makes the next ``reset()`` start env ``i`` from
``s + i``, as Gymnasium's vector env and SB3's ``DummyVecEnv`` both do.

Every step copies the actions to the device and the observations back, and builds K info dicts: for thousands of
envs :mod:`dpr.rl.batched_ppo` keeps the loop on the device instead; this adapter is for SB3's other algorithms
and for checking one against the other.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv


class BatchedSB3VecEnv(VecEnv):
    """SB3's ``VecEnv`` over a batched vector env (module docstring); ``vector_env`` may be wrapped."""

    def __init__(self, vector_env):
        self.vector_env = vector_env
        self.env = vector_env.unwrapped
        super().__init__(self.env.num_envs, self.env.single_observation_space, self.env.single_action_space)
        self._actions: np.ndarray | None = None
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, dtype=np.int64)
        self._started = time.time()

    # -- stepping ---------------------------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        seeds = None if self._seeds[0] is None else [int(seed) for seed in self._seeds]
        observation = self.env.reset_tensors(seed=seeds)
        self._reset_seeds()
        self._reset_options()
        self._returns[:] = 0
        self._lengths[:] = 0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return observation.cpu().numpy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        env = self.env
        actions = torch.as_tensor(np.asarray(self._actions), device=env.device)
        observation, reward, terminated, truncated, final = env.step_tensors(actions)
        reward, terminated, truncated = (value.cpu().numpy() for value in (reward, terminated, truncated))
        dones = terminated | truncated
        self._returns += reward
        self._lengths += 1
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if dones.any():
            self._note_ends(infos, np.flatnonzero(dones), final.cpu().numpy(), terminated, truncated)
        return observation.cpu().numpy(), reward.astype(np.float32), dones, infos

    def _note_ends(self, infos: list[dict], ended: np.ndarray, final: np.ndarray, terminated, truncated) -> None:
        """SB3's keys in the info of each env whose episode ended this step; its return and length restart."""
        for i in ended:
            info = infos[i]
            info["terminal_observation"] = final[i]
            info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            info["episode"] = {
                "r": float(self._returns[i]),
                "l": int(self._lengths[i]),
                "t": round(time.time() - self._started, 6),
            }
            info["is_success"] = bool(terminated[i])  # the task's end is reaching the goal
        self._returns[ended] = 0
        self._lengths[ended] = 0

    def close(self) -> None:
        self.vector_env.close()

    # -- SB3's env access ---------------------------------------------------------------------------------------
    def _indices(self, indices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The vector env's attribute (else the single env's, its template's), once per index: every env of the
        batch has the same settings."""
        value = getattr(self.env, attr_name) if hasattr(self.env, attr_name) else getattr(self.env.template, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        """Set an attribute of the vector env: of every env at once (``indices`` must name all of them)."""
        if len(self._indices(indices)) != self.num_envs:
            raise ValueError("the batched engine's envs share their settings: set an attribute of all of them")
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        """Call the single env's method (its template's) once, and give its result for every index."""
        result = getattr(self.env.template, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]

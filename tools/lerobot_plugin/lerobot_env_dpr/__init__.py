"""dpr's tasks as a LeRobot environment: ``lerobot-eval --env.discover_packages_path=lerobot_env_dpr --env.type=dpr``.

Importing this package registers, for LeRobot, the ``EnvConfig`` subclass ``dpr`` (:class:`DprEnv`), and, for
Gymnasium, one id ``lerobot_env_dpr/<Task>`` per dpr task (``lerobot_env_dpr/Navigation-v0`` ...): the dpr env
wrapped by :class:`LeRobotObservation`, which speaks what LeRobot's ``lerobot-eval`` reads, the way ``gym_pusht``
does for PushT:

- observations ``{"agent_pos": <the state observation>, "environment_state": <env.environment_state()>}``, which
  ``lerobot.envs.utils.preprocess_observation`` turns into ``observation.state`` and
  ``observation.environment_state``, the features dpr datasets record;
- actions: one continuous value per robot, as the policy's postprocessor returns it, turned into the env's
  MultiBinary action by :func:`decode_actions` (``--env.actions``: "expand", a robot expands where its value is
  above one half, as recorded actions are 0 or 1; "phase" for a policy trained on phases);
- a seeded reset also seeds torch, so a policy that samples (Diffusion Policy) draws the same noise as in
  ``tools/lerobot_policies.py evaluate`` on that seed: with ``--eval.batch_size=1`` both score an episode alike;
- reward: the step's gain in projected displacement (the paper's metric), so LeRobot's ``sum_reward`` of an
  episode is its projected displacement, the number ``dpr evaluate`` reports; ``info["is_success"]`` is the
  env's (the swarm within 10 units of the goal).

The package imports LeRobot; dpr never imports it (dpr does not depend on LeRobot). It lives in
``tools/lerobot_plugin``, which ``tools/lerobot_env.sh`` puts on the side environment's path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import register, registry

import dpr  # noqa: F401  (registers dpr's env ids)
from dpr.envs import TASKS, episode_steps

PACKAGE = "lerobot_env_dpr"
AGENT_POS, ENVIRONMENT_STATE = "agent_pos", "environment_state"
ACTION_KINDS = ("expand", "phase")  # what the policy's action values are: 0/1 expansions, or phases


def decode_actions(values, kind: str = "expand") -> np.ndarray:
    """The env's 0/1 action from a policy's per-robot values: for "expand" (trained on 0/1 actions) the robots
    above one half; for "phase" (trained on phases, 1 = expanding now, 0 = one decision ahead, ...) the robots
    within half a decision of the most advanced one, which is the recorded action exactly where the most advanced
    is 1, and always expands some robot (a swarm with none expanded is a state the demonstrations hardly hold)."""
    values = np.asarray(values, np.float64).reshape(-1)
    if kind not in ACTION_KINDS:
        raise ValueError(f"action kind must be one of {ACTION_KINDS}, got {kind!r}")
    limit = values.max() - 0.5 if kind == "phase" else 0.5
    return (values > limit).astype(np.int8)


class LeRobotObservation(gym.Wrapper):
    """A dpr env as LeRobot's evaluation reads an env: dict observations of ``agent_pos`` and
    ``environment_state``, continuous per-robot actions decoded by :func:`decode_actions`, and the step's gain in
    projected displacement as its reward."""

    def __init__(self, env: gym.Env, actions: str = "expand"):
        super().__init__(env)
        base = env.unwrapped
        if base.obs_type != "state" or base.action_type != "multibinary":
            raise ValueError(f"{PACKAGE}: needs obs_type='state' and action_type='multibinary', got "
                             f"{base.obs_type!r} and {base.action_type!r}")  # fmt: skip
        decode_actions([0.0], actions)  # a ValueError for an unknown kind, before the first episode
        self.actions = actions
        n_state = len(base.environment_state_names)
        self.observation_space = gym.spaces.Dict({
            AGENT_POS: env.observation_space,
            ENVIRONMENT_STATE: gym.spaces.Box(-np.inf, np.inf, (n_state,), np.float32),
        })  # fmt: skip
        self.action_space = gym.spaces.Box(-np.inf, np.inf, (base.n_robots,), np.float32)
        self._displacement = 0.0

    def _observation(self, state: np.ndarray) -> dict[str, np.ndarray]:
        return {AGENT_POS: np.asarray(state, np.float32), ENVIRONMENT_STATE: self.env.unwrapped.environment_state()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:  # the policy's own noise (Diffusion's sampling) drawn from the episode's seed too
            import torch

            torch.manual_seed(seed)
        state, info = self.env.reset(seed=seed, options=options)
        self._displacement = float(info["projected_displacement"])
        return self._observation(state), info

    def step(self, action):
        expand = decode_actions(action, self.actions)
        state, _, terminated, truncated, info = self.env.step(expand)
        gain = float(info["projected_displacement"]) - self._displacement
        self._displacement = float(info["projected_displacement"])
        return self._observation(state), gain, terminated, truncated, info


def make_env(task: str, env_kwargs: dict | None = None, actions: str = "expand", **make_kwargs) -> gym.Env:
    """``dpr/<task>`` made with ``env_kwargs``, wrapped by :class:`LeRobotObservation` (the entry point of the
    ``lerobot_env_dpr/<task>`` ids)."""
    return LeRobotObservation(gym.make(f"dpr/{task}", **(env_kwargs or {}), **make_kwargs), actions)


def register_envs() -> None:
    """One Gymnasium id ``lerobot_env_dpr/<Task>`` per dpr task id ``dpr/<Task>``."""
    for env_id in TASKS:
        task = env_id.split("/", 1)[1]
        if f"{PACKAGE}/{task}" not in registry:
            register(id=f"{PACKAGE}/{task}", entry_point=f"{PACKAGE}:make_env", kwargs={"task": task})


register_envs()

try:
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.envs.configs import EnvConfig
except ImportError as error:  # the gym ids above work without LeRobot; the EnvConfig needs it
    raise ImportError(f"{PACKAGE} registers a LeRobot EnvConfig and needs LeRobot: `make lerobot-env` builds "
                      "the side environment (docs/lerobot-policies.md)") from error  # fmt: skip


@EnvConfig.register_subclass("dpr")
@dataclass
class DprEnv(EnvConfig):
    """A dpr task for ``lerobot-eval --env.type=dpr``. Its fields are the dpr env's (``--env.task=Gate-v2``,
    ``--env.n_robots=9``, ...); the defaults are the Navigation demonstrations of docs/lerobot-policies.md: 9
    paddle robots deciding every 6 physics steps, the previous action in the observation, episodes of 2500
    physics steps. The policy's features (``observation.state``, ``observation.environment_state``, ``action``)
    are read from the env those fields make."""

    task: str | None = "Navigation-v0"
    fps: int = 2  # decisions per simulated second, rounded (10 / action_repeat); LeRobot uses it for videos only
    n_robots: int = 9
    robot_model: str = "paddle"
    action_repeat: int = 6
    obs_last_action: bool = True
    episode_physics_steps: int = 2500
    actions: str = "expand"  # "phase" for a policy trained on phases (ACT's recipe): decode_actions
    render_size: int = 128  # lerobot-eval records videos of the first episodes; small frames keep that cheap
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        env = make_env(self.task, self.env_kwargs)
        try:
            n_state = env.observation_space[AGENT_POS].shape
            n_env = env.observation_space[ENVIRONMENT_STATE].shape
        finally:
            env.close()
        self.features = {
            "action": PolicyFeature(type=FeatureType.ACTION, shape=(self.n_robots,)),
            AGENT_POS: PolicyFeature(type=FeatureType.STATE, shape=n_state),
            ENVIRONMENT_STATE: PolicyFeature(type=FeatureType.ENV, shape=n_env),
        }
        self.features_map = {
            "action": "action",
            AGENT_POS: "observation.state",
            ENVIRONMENT_STATE: "observation.environment_state",
        }
        check_policy_features(self)

    @property
    def env_kwargs(self) -> dict:
        """The dpr env's keyword arguments these fields set."""
        kwargs = {"n_robots": self.n_robots, "robot_model": self.robot_model, "obs_last_action": self.obs_last_action}
        return {**kwargs, **({"action_repeat": self.action_repeat} if self.action_repeat > 1 else {})}

    @property
    def package_name(self) -> str:
        return PACKAGE

    @property
    def gym_id(self) -> str:
        return f"{PACKAGE}/{self.task}"

    @property
    def gym_kwargs(self) -> dict:
        render = {"render_mode": "rgb_array", "render_size": self.render_size}
        return {
            "env_kwargs": {**self.env_kwargs, **render},
            "actions": self.actions,
            "max_episode_steps": episode_steps(self.env_kwargs, self.episode_physics_steps),
        }


def check_policy_features(env: DprEnv) -> None:
    """When ``lerobot-eval`` was given ``--policy.path``: the policy's features must be the env's (robots, state
    and environment-state sizes), a ValueError naming both before any episode runs (else LeRobot loads the
    weights and fails inside the network, or a policy of another N runs on the first robots)."""
    import json
    from pathlib import Path

    from lerobot.configs import parser

    path = parser.get_path_arg("policy")
    config_file = Path(path) / "config.json" if path else None
    if config_file is None or not config_file.is_file():
        return
    config = json.loads(config_file.read_text())
    wanted = {key: list(feature["shape"]) for key, feature in config.get("input_features", {}).items()}
    wanted.update({key: list(feature["shape"]) for key, feature in config.get("output_features", {}).items()})
    have = {env.features_map[key]: list(feature.shape) for key, feature in env.features.items()}
    wrong = {key: (shape, have.get(key)) for key, shape in wanted.items() if have.get(key) != shape}
    if wrong:
        details = "; ".join(f"{key}: policy {shape}, env {got}" for key, (shape, got) in wrong.items())
        raise ValueError(
            f"--policy.path={path} does not fit --env ({env.task}, n_robots={env.n_robots}): {details}. "
            "Set --env.n_robots and the other --env fields to the policy's dataset"
        )

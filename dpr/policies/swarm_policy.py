"""An actor-critic policy for the swarm state whose actor is one small network shared by every robot.

The centralised MLP maps the whole state to N logits, one output unit per robot index: what it learns about
robot 3 teaches it nothing about robot 5, and a clone of the Unresponsive teacher fits its training frames far
better than held-out episodes (whole-action match 0.72 against 0.44). The wave's rule is the same for every
robot: expand when your bin, counted along the goal direction, is the one after the bin that expanded last. This
actor computes it the same way for every robot (Deep Sets, Zaheer et al. 2017):

- each robot's features in the frame of the goal direction (so that a rotated swarm is the same swarm): its
  distance along the goal direction relative to the nearest robot's, its offset across it from the swarm's
  centre, its velocity in that frame, its angular velocity, its expansion and its last action;
- ``phi``, one MLP applied to every robot, then the mean and the max of its outputs over the swarm;
- ``rho``, one MLP applied to every robot on its own ``phi`` output, the two pooled vectors and the swarm's
  globals (the held count, the distance to the goal, the object's position and velocity and the task's landmarks'
  positions, such as Gate's opening, in the same frame);
- one linear unit, shared, from each robot's ``rho`` output to its logit.

Robots stay exchangeable: permuting the robots permutes the logits. The critic is SB3's usual MLP on the whole
state (``net_arch``), or with ``critic="swarm"`` a Deep Sets network of its own: ``phi`` on every robot, the mean
and the max over the swarm with the globals, then the ``net_arch`` layers to the value. That critic has no weight
that depends on N either, and permuting the robots leaves the value as it is. The model is an ordinary SB3
PPO/A2C model: ``dpr bc`` clones into it, ``dpr finetune`` trains it, ``dpr evaluate`` runs it. It is chosen with
``policy: SwarmPolicy`` in a hyperparameter entry (and the critic with ``policy_kwargs: {critic: swarm}``).

No weight of the actor depends on N, so a model trained on N robots acts for any other number: ``dpr evaluate``,
``dpr collect`` and ``dpr view`` take ``--n-robots`` with it (:func:`dpr.policies.sb3.load_model` rebuilds the
policy for the env's spaces with the same actor, and the same critic when it is the swarm one). The MLP critic reads
the state of N robots, so such a model trains at its N only.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import create_mlp
from torch import nn

from dpr.envs.particle_env import LANDMARK_FEATURES, LENGTH_SCALE, OBJECT_FEATURES, ROBOT_FEATURES
from dpr.policies.features import GoalFrame
from dpr.policies.model_file import SWARM_POLICY  # its name in a hyperparameter entry's `policy`
from dpr.policies.wave import BIN_WIDTH

__all__ = ["SwarmActorCriticPolicy"]

CRITICS = ("mlp", "swarm")  # SB3's MLP on the whole state; a Deep Sets critic (module docstring)
ROBOT_INPUTS = 7  # along, across, velocity along and across, angular velocity, expansion, last action
# Positions and velocities in units of the wave's bin width (positions are observed in units of 1000).
_BIN = BIN_WIDTH * LENGTH_SCALE


class SwarmLayout:
    """Where the parts of the state observation of ``n_robots`` robots are: the robots' features, the object's
    (Manipulation), the task's ``landmarks`` (fixed points, x and y each: Gate's opening with
    ``observe_opening``) and the last action with its held count (``obs_last_action``); told apart by the size."""

    def __init__(self, size: int, n_robots: int, has_object: bool, landmarks: int = 0):
        self.n_robots = int(n_robots)
        self.object_at = ROBOT_FEATURES * self.n_robots
        self.landmarks_at = self.object_at + (OBJECT_FEATURES if has_object else 0)
        self.memory_at = self.landmarks_at + LANDMARK_FEATURES * int(landmarks)
        rest = size - self.memory_at
        if rest not in (0, self.n_robots + 1):
            parts = f"{'with' if has_object else 'without'} an object"
            if landmarks:
                parts += f" and {landmarks} landmarks"
            raise ValueError(
                f"{SWARM_POLICY}: a state observation of {n_robots} robots {parts} has "
                f"{self.memory_at} or {self.memory_at + self.n_robots + 1} values, got {size}"
            )
        self.has_memory = rest > 0
        self.has_object = bool(has_object)
        self.landmarks = int(landmarks)
        # held count, distance to goal, object, landmarks
        self.globals = 2 + (OBJECT_FEATURES if has_object else 0) + LANDMARK_FEATURES * self.landmarks

    def split(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(robots (B, N, 7), globals (B, G))`` in the goal direction's frame."""
        n = self.n_robots
        robots = obs[:, : self.object_at].reshape(-1, n, ROBOT_FEATURES)
        positions, velocities = robots[..., 0:2] / _BIN, robots[..., 2:4] / _BIN
        frame = GoalFrame(positions)
        # signed, unlike the wave's absolute distance: a swarm that passed the goal stays ordered along its way
        along = frame.along(positions)
        along = along - along.min(dim=1, keepdim=True).values
        across = frame.across(positions)
        if self.has_memory:
            last_action = obs[:, self.memory_at : self.memory_at + n]
            held = obs[:, self.memory_at + n : self.memory_at + n + 1]
        else:
            last_action = torch.zeros_like(along)
            held = torch.zeros_like(along[:, :1])
        per_robot = torch.cat(
            [along[..., None], across[..., None], frame.rotate(velocities), robots[..., 4:6], last_action[..., None]],
            2,
        )
        swarm = [held, frame.distance[:, 0] / 10.0]  # the distance in tens of bin widths
        if self.has_object:
            thing = obs[:, self.object_at : self.landmarks_at].reshape(-1, 2, 2) / _BIN  # position, velocity
            swarm += [frame.rotate(thing[:, :1] - frame.centre)[:, 0] / 10.0, frame.rotate(thing[:, 1:])[:, 0]]
        if self.landmarks:  # each relative to the swarm's centre, like the object
            points = obs[:, self.landmarks_at : self.memory_at].reshape(-1, self.landmarks, 2) / _BIN
            swarm.append(frame.rotate(points - frame.centre).flatten(1) / 10.0)
        return per_robot, torch.cat(swarm, 1)


class SwarmExtractor(nn.Module):
    """SB3's ``mlp_extractor`` for :class:`SwarmActorCriticPolicy`: ``policy_net`` is the shared per-robot actor
    (its latent is every robot's ``rho`` output, flattened), ``value_net`` SB3's MLP on the whole state or, with
    ``critic="swarm"``, a per-robot ``phi`` pooled over the swarm and an MLP from the pool to the value's latent."""

    def __init__(
        self,
        layout: SwarmLayout,
        features_dim: int,
        robot_net: list[int],
        vf_net: list[int],
        activation,
        critic: str = "mlp",
    ):
        super().__init__()
        self.layout = layout
        self.critic = critic
        hidden = int(robot_net[-1])
        self.policy_net = nn.ModuleDict(
            {
                "phi": nn.Sequential(*create_mlp(ROBOT_INPUTS, -1, robot_net, activation)),
                "rho": nn.Sequential(*create_mlp(3 * hidden + layout.globals, -1, robot_net, activation)),
            }
        )
        if critic == "swarm":
            self.value_net = nn.ModuleDict(
                {
                    "phi": nn.Sequential(*create_mlp(ROBOT_INPUTS, -1, robot_net, activation)),
                    "rho": nn.Sequential(*create_mlp(2 * hidden + layout.globals, -1, vf_net, activation)),
                }
            )
            self.latent_dim_vf = int(vf_net[-1]) if vf_net else 2 * hidden + layout.globals
        else:
            self.value_net = nn.Sequential(*create_mlp(features_dim, -1, vf_net, activation))
            self.latent_dim_vf = int(vf_net[-1]) if vf_net else features_dim
        self.hidden = hidden
        self.latent_dim_pi = layout.n_robots * hidden

    @staticmethod
    def _pooled(each: torch.Tensor, swarm: torch.Tensor) -> torch.Tensor:
        """The mean and the max over the swarm of every robot's ``phi`` output, with the swarm's globals."""
        return torch.cat([each.mean(1), each.amax(1), swarm], 1)

    def forward_actor_parts(self, robots: torch.Tensor, swarm: torch.Tensor) -> torch.Tensor:
        """The actor's latent from the split observation (:meth:`SwarmLayout.split`)."""
        each = self.policy_net["phi"](robots)
        pooled = self._pooled(each, swarm)
        # rho's first layer reads [each, pooled]; the pooled half is the same for every robot of a swarm, so it is
        # multiplied once per swarm (N times fewer products, and no [B, N, 3h + G] copy), with the same weights.
        first, *rest = self.policy_net["rho"]  # (slicing the Sequential would build a new module every call)
        per_robot = nn.functional.linear(each, first.weight[:, : self.hidden])
        latent = per_robot + nn.functional.linear(pooled, first.weight[:, self.hidden :], first.bias)[:, None, :]
        for layer in rest:
            latent = layer(latent)
        return latent.flatten(1)

    def _swarm_critic(self, robots: torch.Tensor, swarm: torch.Tensor) -> torch.Tensor:
        return self.value_net["rho"](self._pooled(self.value_net["phi"](robots), swarm))

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.forward_actor_parts(*self.layout.split(features))

    def forward_critic(
        self, features: torch.Tensor, parts: tuple[torch.Tensor, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """The critic's latent; ``parts``: ``self.layout.split(features)`` where it is already computed."""
        if self.critic != "swarm":
            return self.value_net(features)
        return self._swarm_critic(*(parts if parts is not None else self.layout.split(features)))

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.critic != "swarm":
            return self.forward_actor(features), self.value_net(features)
        parts = self.layout.split(features)  # once for both
        return self.forward_actor_parts(*parts), self._swarm_critic(*parts)


class RobotLogits(nn.Module):
    """One linear unit, shared by every robot, from its latent to its Bernoulli logit."""

    def __init__(self, hidden: int):
        super().__init__()
        self.hidden = hidden
        self.unit = nn.Linear(hidden, 1)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.unit(latent.reshape(latent.shape[0], -1, self.hidden)).squeeze(2)


class SwarmActorCriticPolicy(ActorCriticPolicy):
    """SB3's ActorCriticPolicy with a shared per-robot actor (module docstring) for MultiBinary(N) actions.
    ``robot_net`` is the layer sizes of ``phi`` and ``rho``; ``net_arch`` (a list) the critic's; ``critic`` one of
    :data:`CRITICS`. ``has_object`` and ``landmarks`` (a count) describe the env's state (:class:`SwarmLayout`); the
    model builder reads them off the env."""

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        action_space: gym.spaces.MultiBinary,
        lr_schedule,
        *,  # SB3 gives every argument after the learning-rate schedule by name (policy_kwargs, a saved model's data)
        has_object: bool = False,
        landmarks: int = 0,
        robot_net: list[int] | None = None,
        critic: str = "mlp",
        **kwargs,
    ):
        if not isinstance(action_space, gym.spaces.MultiBinary) or len(action_space.shape) != 1:
            raise ValueError(f"{SWARM_POLICY} needs MultiBinary(N) actions, got {action_space}")
        if not isinstance(observation_space, gym.spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"{SWARM_POLICY} needs the 1-D state observation, got {observation_space}")
        if critic not in CRITICS:
            raise ValueError(f"{SWARM_POLICY}: critic must be one of {CRITICS}, got {critic!r}")
        self.layout = SwarmLayout(observation_space.shape[0], action_space.n, has_object, landmarks)
        self.robot_net = list(robot_net or [64, 64])
        self.critic = critic
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def observation_parts(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The robots' features and the swarm's globals of a batch of observations (:meth:`SwarmLayout.split`),
        which :meth:`evaluate_actions` takes ready: a learner that evaluates the same observations every epoch
        splits them once."""
        features = self.extract_features(obs)
        return self.layout.split(features if self.share_features_extractor else features[0])

    def evaluate_actions(self, obs: torch.Tensor, actions: torch.Tensor, parts=None):
        """SB3's, with ``parts`` (:meth:`observation_parts` of ``obs``) where they are already computed."""
        if parts is None:
            return super().evaluate_actions(obs, actions)
        features = self.extract_features(obs)
        latent_pi = self.mlp_extractor.forward_actor_parts(*parts)
        latent_vf = self.mlp_extractor.forward_critic(features if self.share_features_extractor else features[1], parts)
        distribution = self._get_action_dist_from_latent(latent_pi)
        return self.value_net(latent_vf), distribution.log_prob(actions), distribution.entropy()

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.update(
            has_object=self.layout.has_object,
            landmarks=self.layout.landmarks,
            robot_net=self.robot_net,
            critic=self.critic,
        )
        return data

    def _build_mlp_extractor(self) -> None:
        vf_net = self.net_arch["vf"] if isinstance(self.net_arch, dict) else list(self.net_arch)
        self.mlp_extractor = SwarmExtractor(
            self.layout, self.features_dim, self.robot_net, vf_net, self.activation_fn, self.critic
        )

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # SB3 made one Linear(N * hidden, N); every robot's logit comes from the same unit instead.
        self.action_net = RobotLogits(self.mlp_extractor.hidden)
        if self.ortho_init:
            self.action_net.apply(lambda module: self.init_weights(module, gain=0.01))
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

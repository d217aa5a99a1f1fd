"""SwarmActorCriticPolicy (`policy: SwarmPolicy`): a shared per-robot actor that sees the whole swarm."""

import re

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import rotate_scene, visited_observations
from helpers import run_cli as run
from stable_baselines3.common.vec_env import DummyVecEnv

from dpr.datasets.collect import CollectSpec, collect
from dpr.datasets.lerobot import LeRobotReader
from dpr.envs.particle_env import ROBOT_FEATURES
from dpr.imitation import CloneConfig, behaviour_clone
from dpr.policies.hyperparams import SWARM_CRITICS, load_hyperparams
from dpr.policies.model_file import ModelInfo, has_swarm_actor, model_env_kwargs
from dpr.policies.sb3 import (
    VALUE_HEAD_PREFIXES,
    build_model,
    load_initial_policy,
    load_model,
    load_model_policy,
    save_model,
)
from dpr.policies.swarm_policy import CRITICS, RobotLogits, SwarmActorCriticPolicy
from dpr.rl.train import TrainConfig, train

N = 5
SWARM = {"policy": "SwarmPolicy", "policy_kwargs": {"net_arch": [16], "robot_net": [16, 8]}}
ENVS = [
    ("dpr/Navigation-v0", {"obs_last_action": True}),
    ("dpr/Unresponsive-v0", {"obs_last_action": True}),
    ("dpr/Manipulation-v0", {"obs_last_action": True}),
    ("dpr/Navigation-v0", {}),
    ("dpr/Gate-v2", {"obs_last_action": True}),
]
IDS = ["navigation", "unresponsive", "manipulation-object", "navigation-no-memory", "gate-opening"]


def swarm_model(env_id, kwargs, seed=0, n_robots=N):
    env = gym.make(env_id, n_robots=n_robots, robot_model="disk", **kwargs)
    model = build_model(load_hyperparams("ppo", env_id, overrides=SWARM), DummyVecEnv([lambda: env]), seed, None)
    return model, env


def logits(model, observations: np.ndarray) -> np.ndarray:
    policy = model.policy
    with torch.no_grad():
        features = policy.extract_features(torch.as_tensor(observations), policy.pi_features_extractor)
        return policy.action_net(policy.mlp_extractor.forward_actor(features)).numpy()


def robots_permuted(observations: np.ndarray, layout, order: np.ndarray) -> np.ndarray:
    """``observations`` with the robots (their features and, when observed, their last actions) in ``order``."""
    permuted = observations.copy()
    robots = permuted[:, : ROBOT_FEATURES * N].reshape(len(permuted), N, ROBOT_FEATURES)
    robots[:] = robots[:, order]
    if layout.has_memory:
        permuted[:, layout.memory_at : layout.memory_at + N] = observations[:, layout.memory_at :][:, order]
    return permuted


def trained_a_little(model) -> None:
    """Weights away from the initialisation (whose output layer is nearly zero), so the tests see real outputs."""
    with torch.no_grad():
        for parameter in model.policy.parameters():
            parameter.add_(0.3 * torch.randn_like(parameter))


@pytest.mark.parametrize(("env_id", "kwargs"), ENVS, ids=IDS)
def test_permuting_the_robots_permutes_the_logits(env_id, kwargs):
    model, env = swarm_model(env_id, kwargs)
    trained_a_little(model)
    observations = visited_observations(env, seeds=(0, 1), steps=10)
    base = logits(model, observations)
    assert base.shape == (len(observations), N) and np.ptp(base) > 0.1
    rng = np.random.default_rng(0)
    for _ in range(3):
        order = rng.permutation(N)
        permuted = robots_permuted(observations, model.policy.layout, order)
        np.testing.assert_allclose(logits(model, permuted), base[:, order], atol=1e-5)
    env.close()


@pytest.mark.parametrize(("env_id", "kwargs"), ENVS, ids=IDS)
def test_rotating_the_scene_about_the_goal_leaves_the_actor_unchanged(env_id, kwargs):
    model, env = swarm_model(env_id, kwargs)
    trained_a_little(model)
    observations = visited_observations(env, seeds=(2,), steps=15)
    base = logits(model, observations)
    layout = model.policy.layout
    for angle in (0.7, np.pi / 2, 2.5, -1.9):
        landmarks = slice(layout.landmarks_at, layout.memory_at)
        rotated = rotate_scene(observations, N, angle, layout.object_at if layout.has_object else None, landmarks)
        np.testing.assert_allclose(logits(model, rotated), base, atol=2e-4)
    # the object and the landmarks are seen: moving them changes the logits
    for seen, at in ((layout.has_object, layout.object_at), (layout.landmarks, layout.landmarks_at)):
        if seen:
            moved = observations.copy()
            moved[:, at] += 0.05
            assert not np.allclose(logits(model, moved), base, atol=1e-3)
    env.close()


def test_the_actor_shares_one_network_across_robots_and_other_swarm_sizes_keep_its_shapes():
    model, env = swarm_model("dpr/Navigation-v0", {"obs_last_action": True})
    policy = model.policy
    assert isinstance(policy, SwarmActorCriticPolicy) and isinstance(policy.action_net, RobotLogits)
    # the actor's weights do not grow with the swarm: the same shapes at N = 5 and N = 9
    big, big_env = swarm_model("dpr/Navigation-v0", {"obs_last_action": True}, n_robots=9)

    def actor_shapes(p):
        return {name: tuple(t.shape) for name, t in p.named_parameters() if not name.startswith(VALUE_HEAD_PREFIXES)}

    assert actor_shapes(big.policy) == actor_shapes(policy)
    assert actor_shapes(policy)["action_net.unit.weight"] == (1, 8)
    # every parameter is in the optimizer that PPO steps
    optimised = {id(p) for group in policy.optimizer.param_groups for p in group["params"]}
    assert optimised == {id(p) for p in policy.parameters()}
    env.close()
    big_env.close()


@pytest.mark.parametrize("env_id, kwargs", ENVS[:3] + ENVS[4:], ids=IDS[:3] + IDS[4:])
def test_rho_reads_each_robot_beside_the_pooled_swarm_as_one_layer_on_their_concatenation(env_id, kwargs):
    """The actor multiplies rho's pooled half once per swarm: it must be the layer on [each robot, pooled]."""
    model, env = swarm_model(env_id, kwargs)
    extractor = model.policy.mlp_extractor
    observations = torch.as_tensor(visited_observations(env, steps=8), dtype=torch.float32)
    robots, swarm = extractor.layout.split(observations)
    each = extractor.policy_net["phi"](robots)
    pooled = torch.cat([each.mean(1), each.max(1).values, swarm], 1)
    joint = torch.cat([each, pooled[:, None, :].expand(-1, N, -1)], 2)
    with torch.no_grad():
        reference = extractor.policy_net["rho"](joint).flatten(1)
        torch.testing.assert_close(extractor.forward_actor(observations), reference, rtol=0, atol=1e-5)
        # the pooled half matters: zeroing its weights changes the actor
        extractor.policy_net["rho"][0].weight[:, extractor.hidden :] = 0
        assert not torch.allclose(extractor.forward_actor(observations), reference, atol=1e-3)
    env.close()


@pytest.mark.parametrize("critic", CRITICS)
def test_actions_evaluated_on_observation_parts_split_before_are_sb3s_evaluation(critic):
    """The batched PPO splits its rollout's observations once and evaluates every epoch's mini-batches on the parts:
    the same values, log-probabilities and entropies as SB3's evaluate_actions on the observations."""
    env_id, kwargs = ENVS[4]
    env = gym.make(env_id, n_robots=N, robot_model="disk", **kwargs)
    overrides = {**SWARM, "policy_kwargs": {**SWARM["policy_kwargs"], "critic": critic}}
    model = build_model(load_hyperparams("ppo", env_id, overrides=overrides), DummyVecEnv([lambda: env]), 0, None)
    trained_a_little(model)
    policy = model.policy
    observations = torch.as_tensor(visited_observations(env, steps=8), dtype=torch.float32)
    actions = torch.randint(0, 2, (len(observations), N), generator=torch.Generator().manual_seed(0)).float()
    with torch.no_grad():
        parts = policy.observation_parts(observations)
        assert parts[0].shape == (len(observations), N, 7)
        for given, sb3 in zip(
            policy.evaluate_actions(observations, actions, parts=parts), policy.evaluate_actions(observations, actions)
        ):
            torch.testing.assert_close(given, sb3, rtol=0, atol=1e-6)
        # the parts are what is evaluated: other parts, other log-probabilities
        moved = (parts[0] + 1.0, parts[1])
        changed = policy.evaluate_actions(observations, actions, parts=moved)[1]
        assert not torch.allclose(changed, policy.evaluate_actions(observations, actions)[1], atol=1e-3)
    env.close()


def test_the_layout_is_checked():
    with pytest.raises(ValueError, match="SwarmPolicy: a state observation of 5 robots without an object has 30 or 36"):
        SwarmActorCriticPolicy(
            gym.spaces.Box(-np.inf, np.inf, (31,), dtype=np.float32), gym.spaces.MultiBinary(5), lambda _: 1e-3
        )
    with pytest.raises(ValueError, match="SwarmPolicy needs MultiBinary"):
        SwarmActorCriticPolicy(
            gym.spaces.Box(-np.inf, np.inf, (30,), dtype=np.float32), gym.spaces.Discrete(32), lambda _: 1e-3
        )
    with pytest.raises(ValueError, match="policy_kwargs may only set"):
        load_hyperparams("ppo", "dpr/Navigation-v0", overrides={"policy_kwargs": {"robot_nets": [8]}})
    for bad in ([], [8, 0], 16):
        with pytest.raises(ValueError, match="policy_kwargs.robot_net"):
            load_hyperparams("ppo", "dpr/Navigation-v0", overrides={"policy_kwargs": {"robot_net": bad}})


DEMO_ENV, DEMO_KWARGS = "dpr/Unresponsive-v0", {"obs_last_action": True}


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """Three 40-step Markov-wave episodes of 5 disk robots with the last action in the observation."""
    root = tmp_path_factory.mktemp("swarm") / "demos"
    spec = CollectSpec(DEMO_ENV, policy="wave-markov", steps=40, n_robots=N, robot_model="disk", env_kwargs=DEMO_KWARGS)
    collect(root, spec, episodes=3)
    return root


def test_dpr_bc_clones_into_the_swarm_actor_with_a_hyperparam(demos, tmp_path, capsys):
    args = ["bc", "--dataset", str(demos), "--env", DEMO_ENV, "--epochs", "1", "--out"]
    assert run([*args, str(tmp_path / "bc"), "--hyperparam", "policy=SwarmPolicy"]) == 0
    model, _ = load_model(tmp_path / "bc" / "model.zip")
    assert isinstance(model.policy, SwarmActorCriticPolicy) and model.policy.robot_net == [64, 64]
    assert run([*args, str(tmp_path / "bad"), "--hyperparam", "policy_kwargs={robot_nets: [8]}"]) == 2
    assert "policy_kwargs may only set" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_clone_runs_saves_loads_and_fine_tunes(demos, tmp_path):
    """BC clones into it, the model file reloads to the same actions, and PPO fine-tunes it from the file."""
    env_id, kwargs = DEMO_ENV, DEMO_KWARGS
    clone = behaviour_clone(
        demos, env_id, CloneConfig(epochs=3, hyperparams=SWARM, lr=3e-3), out=tmp_path / "bc", log=lambda _: None
    )
    assert clone.history[-1]["val_nll"] < clone.history[0]["val_nll"]
    model, _ = load_model(clone.model_path)
    assert isinstance(model.policy, SwarmActorCriticPolicy) and model.policy.robot_net == [16, 8]
    env = gym.make(env_id, n_robots=N, robot_model="disk", **kwargs)
    policy = load_model_policy(clone.model_path, env)
    observation, _ = env.reset(seed=3)
    for _ in range(5):
        action = policy(observation)
        assert action.shape == (N,) and set(np.unique(action)) <= {0, 1}
        np.testing.assert_array_equal(model.predict(observation, deterministic=True)[0], action)
        observation, *_ = env.step(action)
    env.close()
    config = TrainConfig(
        env_id=env_id, n_robots=N, robot_model="disk", seed=0, n_envs=1, steps_per_episode=40, env_kwargs=kwargs,
        algo="ppo", timesteps=64, preset="finetune", init_from=str(clone.model_path), critic_warmup=32,
        hyperparams={**SWARM, "n_steps": 32, "batch_size": 16},
    )  # fmt: skip
    result = train(config, tmp_path / "ft", log=lambda _: None)
    tuned, _ = load_model(result.model_path)
    assert isinstance(tuned.policy, SwarmActorCriticPolicy)
    moved = [
        not torch.equal(a, b)
        for (name, a), b in zip(tuned.policy.state_dict().items(), model.policy.state_dict().values(), strict=True)
        if name.startswith("mlp_extractor.policy_net")
    ]
    assert any(moved)  # the actor trained after the warm-up


def test_a_swarm_model_acts_at_any_swarm_size_but_trains_only_at_its_own(tmp_path, capsys):
    """The actor is shared by the robots: a model of N robots acts for N' robots with the same weights (its critic,
    which reads the whole state, is not carried over). An MLP model is refused at another N."""
    env_id, kwargs = "dpr/Navigation-v0", {"obs_last_action": True}
    model, env = swarm_model(env_id, kwargs)
    trained_a_little(model)
    info = ModelInfo("ppo", env_id, {"n_robots": N, "robot_model": "disk", **kwargs})
    path = save_model(model, tmp_path / "swarm.zip", info)
    assert has_swarm_actor(path)
    assert model_env_kwargs(path, env_id, {"n_robots": 7})["n_robots"] == 7

    big_env = gym.make(env_id, n_robots=7, robot_model="disk", **kwargs)
    big, _ = load_model(path, big_env)
    actor = {name: t for name, t in model.policy.state_dict().items() if not name.startswith(VALUE_HEAD_PREFIXES)}
    resized = big.policy.state_dict()
    assert all(torch.equal(resized[name], t) for name, t in actor.items())
    observation, _ = big_env.reset(seed=0)
    action = load_model_policy(path, big_env)(observation)
    assert action.shape == (7,) and set(np.unique(action)) <= {0, 1}
    # saved at N' and resized back to N, it gives the logits it gave before
    big_path = save_model(big, tmp_path / "swarm7.zip", ModelInfo("ppo", env_id, {**info.env_kwargs, "n_robots": 7}))
    back, _ = load_model(big_path, env)
    assert back.observation_space == env.observation_space
    observations = visited_observations(env, seeds=(0,), steps=5)
    np.testing.assert_allclose(logits(back, observations), logits(model, observations), rtol=1e-6)

    with pytest.raises(ValueError, match="acts at any swarm size but trains only at its own"):
        load_model(path, big_env, for_training=True)
    mlp = build_model(load_hyperparams("ppo", env_id), DummyVecEnv([lambda: env]), 0, None)
    mlp_path = save_model(mlp, tmp_path / "mlp.zip", info)
    assert not has_swarm_actor(mlp_path)
    with pytest.raises(ValueError, match="n_robots=5; n_robots=7 makes a different observation"):
        model_env_kwargs(mlp_path, env_id, {"n_robots": 7})

    argv = ["evaluate", "--policy", str(path), "--env", env_id, "--n-robots", "7", "--steps", "20", "--seeds", "0"]
    assert run([*argv, "--workers", "1"]) == 0
    assert "dpr/Navigation-v0" in capsys.readouterr().out
    # dpr collect records it on its own env kwargs (disk robots, the last action observed) at the N asked for
    argv = ["collect", "--policy", str(path), "--env", env_id, "--n-robots", "7", "--steps", "5", "--episodes", "1"]
    assert run([*argv, "--workers", "1", "--out", str(tmp_path / "ds")]) == 0
    (episode,) = LeRobotReader(tmp_path / "ds").episodes
    assert episode["env_kwargs"] == {**info.env_kwargs, "n_robots": 7, "max_episode_steps": 5}
    env.close()
    big_env.close()


SWARM_CRITIC = {**SWARM, "policy_kwargs": {**SWARM["policy_kwargs"], "critic": "swarm"}}


def values(model, observations: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return model.policy.predict_values(torch.as_tensor(observations)).numpy()[:, 0]


@pytest.mark.parametrize(("env_id", "kwargs"), [ENVS[i] for i in (1, 2, 4)], ids=[IDS[i] for i in (1, 2, 4)])
def test_the_swarm_critic_ignores_the_robots_order_and_takes_any_swarm_size(env_id, kwargs, tmp_path):
    """With ``critic: swarm`` the value is the same for any order of the robots, and a model saved at N values a
    swarm of N' with the same weights, critic included; the MLP critic's value changes with the order."""
    env = gym.make(env_id, n_robots=N, robot_model="disk", **kwargs)
    model = build_model(load_hyperparams("ppo", env_id, overrides=SWARM_CRITIC), DummyVecEnv([lambda: env]), 0, None)
    mlp, _ = swarm_model(env_id, kwargs)
    for each in (model, mlp):
        trained_a_little(each)
    observations = visited_observations(env, seeds=(0,), steps=10)
    permuted = robots_permuted(observations, model.policy.layout, np.random.default_rng(1).permutation(N))
    base = values(model, observations)
    assert np.ptp(base) > 1e-3
    np.testing.assert_allclose(values(model, permuted), base, rtol=1e-5, atol=1e-6)
    assert not np.allclose(values(mlp, permuted), values(mlp, observations), atol=1e-4)

    info = ModelInfo("ppo", env_id, {"n_robots": N, "robot_model": "disk", **kwargs})
    path = save_model(model, tmp_path / "swarm-critic.zip", info)
    big_env = gym.make(env_id, n_robots=7, robot_model="disk", **kwargs)
    big, _ = load_model(path, big_env)
    assert big.policy.critic == "swarm"
    assert all(torch.equal(big.policy.state_dict()[name], t) for name, t in model.policy.state_dict().items())
    assert np.isfinite(values(big, visited_observations(big_env, seeds=(0,), steps=3))).all()
    env.close()
    big_env.close()


def test_a_clone_fine_tunes_with_the_swarm_critic_keeping_its_actor(demos, tmp_path):
    """A clone made with the MLP critic starts a fine-tuning run whose critic is the swarm one: its actor's weights
    are the clone's, the critic is new."""
    clone = behaviour_clone(
        demos, DEMO_ENV, CloneConfig(epochs=1, hyperparams=SWARM, lr=3e-3), out=tmp_path / "bc", log=lambda _: None
    )
    source, _ = load_model(clone.model_path)
    env = gym.make(DEMO_ENV, n_robots=N, robot_model="disk", **DEMO_KWARGS)
    model = build_model(
        load_hyperparams("ppo", DEMO_ENV, "finetune", SWARM_CRITIC), DummyVecEnv([lambda: env]), 0, None
    )
    load_initial_policy(model, clone.model_path)
    weights = model.policy.state_dict()
    for name, value in source.policy.state_dict().items():
        if not name.startswith(VALUE_HEAD_PREFIXES):
            assert torch.equal(weights[name], value), name
    assert "mlp_extractor.value_net.phi.0.weight" in weights
    env.close()


@pytest.mark.parametrize(
    ("overrides", "problem"),
    [
        ({"policy_kwargs": {"critic": "swarm"}}, "with policy 'MlpPolicy'"),
        ({**SWARM, "policy_kwargs": {"critic": "deep"}}, "one of ('mlp', 'swarm'); got 'deep'"),
    ],
)
def test_the_critic_setting_is_checked(overrides, problem):
    assert SWARM_CRITICS == CRITICS  # hyperparams checks the names the policy builds
    with pytest.raises(ValueError, match=re.escape(problem)):
        load_hyperparams("ppo", "dpr/Navigation-v0", overrides=overrides)

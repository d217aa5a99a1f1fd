"""Training on the batched engine beyond the tensor PPO's first run: SB3 through the VecEnv adapter (its autoreset and
info conventions), a stopped run resumed to the model an uninterrupted run makes, and models moving between engines
through the commands."""

import dataclasses
import json
import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from helpers import assert_same_policy
from helpers import small_batched_config as small_config

import dpr  # noqa: F401
import dpr.rl.batched_ppo as batched_ppo
from dpr.checks import ParameterError
from dpr.cli import main
from dpr.policies.sb3 import load_model
from dpr.rl.batched_resume import snapshot_file
from dpr.rl.batched_train import train_batched
from dpr.rl.sb3_batched import BatchedSB3VecEnv

REPO = Path(__file__).resolve().parents[1]
NAV = "dpr/Navigation-v0"
QUIET = {"show_progress": False, "log": lambda line: None}


def make_vec(num_envs=3, steps=4, **kwargs):
    kwargs = {"robot_model": "disk", "n_robots": 4, **kwargs}
    return gym.make_vec(
        NAV, num_envs=num_envs, vectorization_mode="vector_entry_point", max_episode_steps=steps, **kwargs
    )


def test_the_adapter_resets_an_ended_env_in_the_same_step_as_sb3_does():
    adapter = BatchedSB3VecEnv(make_vec())
    adapter.seed(5)
    first = adapter.reset()
    reference = make_vec()  # the vector env itself, NEXT_STEP: its step after the end is the reset
    expected_first, _ = reference.reset(seed=5)
    np.testing.assert_array_equal(first, expected_first)
    actions = np.ones((3, 4), dtype=np.int8)
    returns = np.zeros(3)
    for step in range(4):
        observation, rewards, dones, infos = adapter.step(actions)
        final, reward, terminated, truncated, _ = reference.step(actions)
        np.testing.assert_array_equal(rewards, reward)
        returns += reward
        if step < 3:
            assert not dones.any() and infos == [{}, {}, {}]
            np.testing.assert_array_equal(observation, final)
    assert dones.all() and (truncated | terminated).all()
    reset, _, _, _, _ = reference.step(actions)  # NEXT_STEP: the envs start again from their generators
    for i, info in enumerate(infos):
        np.testing.assert_array_equal(info["terminal_observation"], final[i])  # where the episode ended
        np.testing.assert_array_equal(observation[i], reset[i])  # the reset observation, as SB3 expects
        assert info["TimeLimit.truncated"] and info["episode"]["l"] == 4 and info["is_success"] is False
        assert info["episode"]["r"] == pytest.approx(returns[i])
    assert adapter.get_attr("n_robots") == [4, 4, 4] and adapter.env_is_wrapped(gym.Wrapper) == [False] * 3


def test_sb3_ppo_learns_through_the_adapter():
    from stable_baselines3 import PPO

    adapter = BatchedSB3VecEnv(make_vec(num_envs=4, steps=20))
    model = PPO("MlpPolicy", adapter, n_steps=32, batch_size=64, n_epochs=2, seed=0, device="cpu")
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(total_timesteps=384)
    assert model.num_timesteps == 384 and len(model.ep_info_buffer) > 0
    assert any(not torch.equal(a, b) for a, b in zip(before, model.policy.parameters()))


def test_a_stopped_batched_run_resumes_to_the_uninterrupted_runs_model(tmp_path, monkeypatch):
    whole = train_batched(small_config(), tmp_path / "whole", **QUIET)
    calls = {"n": 0}
    real_update = batched_ppo.update

    def stop_at_the_third_update(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real_update(*args, **kwargs)

    monkeypatch.setattr(batched_ppo, "update", stop_at_the_third_update)
    stopped = train_batched(small_config(), tmp_path / "run", snapshot_seconds=0, **QUIET)
    assert stopped.interrupted and snapshot_file(tmp_path / "run").is_file()
    monkeypatch.setattr(batched_ppo, "update", real_update)
    with pytest.raises(ParameterError, match="other settings"):
        train_batched(small_config(seed=1), tmp_path / "run", resume=True, **QUIET)
    resumed = train_batched(small_config(), tmp_path / "run", resume=True, **QUIET)
    assert not resumed.interrupted and not snapshot_file(tmp_path / "run").exists()
    assert_same_policy(resumed.model_path, whole.model_path)
    progress = (tmp_path / "run" / "progress.yaml").read_text()
    assert progress == (tmp_path / "whole" / "progress.yaml").read_text()
    # the checkpoints of the stopped and the resumed part are the uninterrupted run's: one after each of its four
    # updates here (32 steps each, checkpoints every 128 / 4), the last of them the final model
    names = [f"model_{steps}_steps.zip" for steps in (32, 64, 96, 128)]
    for run in ("whole", "run"):
        assert sorted(path.name for path in (tmp_path / run / "checkpoints").iterdir()) == sorted(names)
    for name in names:
        assert_same_policy(tmp_path / "run" / "checkpoints" / name, tmp_path / "whole" / "checkpoints" / name)
    assert_same_policy(tmp_path / "whole" / "checkpoints" / names[-1], whole.model_path)


def test_a_batched_run_makes_its_checkpoints_folder_without_sb3s_warning(tmp_path):
    """SB3 warns 'Path ... does not exist' amid the progress bar when it makes a model's folder itself."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = train_batched(small_config(), tmp_path / "run", **QUIET)
    assert len(list((tmp_path / "run" / "checkpoints").glob("model_*_steps.zip"))) == 4
    assert result.model_path.is_file()


def test_fused_adam_steps_as_adam_does_and_gives_the_setting_back():
    """The tensor PPO's updates step Adam with torch's fused kernel; the model's files keep its own setting."""
    torch.manual_seed(0)
    plain = [torch.nn.Parameter(torch.randn(8, 8)), torch.nn.Parameter(torch.randn(8))]
    fused = [torch.nn.Parameter(weight.detach().clone()) for weight in plain]
    reference, optimizer = torch.optim.Adam(plain, lr=1e-2), torch.optim.Adam(fused, lr=1e-2)
    for _ in range(5):
        for mine, theirs in zip(fused, plain):
            theirs.grad = torch.randn_like(theirs)
            mine.grad = theirs.grad.clone()
        reference.step()
        with batched_ppo.fused_adam(optimizer):
            assert optimizer.param_groups[0]["fused"] is True
            optimizer.step()
        assert optimizer.param_groups[0]["fused"] is None
    for mine, theirs in zip(fused, plain):
        torch.testing.assert_close(mine, theirs, rtol=0, atol=1e-6)


def test_a_learner_moves_with_its_optimisers_state():
    """A resumed run's Adam moments go to the run's device with the weights (Adam refuses them on another device),
    and come back to the CPU with them."""
    env = make_vec(num_envs=4).unwrapped
    hyper, _, _ = small_config().resolve()
    policy = batched_ppo.build_learner(hyper, env.template, 0).policy
    for weight in policy.parameters():
        weight.grad = torch.ones_like(weight)
    policy.optimizer.step()
    moments = lambda: [  # noqa: E731
        value for state in policy.optimizer.state.values() for key, value in state.items() if key != "step"
    ]
    before = [moment.clone() for moment in moments()]
    # what a move to CUDA does to each parameter (new storage under the same Parameter), made here with a dtype: a
    # CPU-only machine has no second device
    batched_ppo.move_learner(policy, torch.float64)
    assert {moment.dtype for moment in moments()} == {torch.float64}
    assert all(weight.dtype == torch.float64 for weight in policy.parameters())
    batched_ppo.move_learner(policy, torch.float32)
    for moment, value in zip(moments(), before, strict=True):
        assert moment.dtype == torch.float32
        torch.testing.assert_close(moment, value, rtol=0, atol=0)


def test_an_update_reports_its_mini_batches_mean_terms_and_stops_past_the_kl_target():
    """The statistics of an update are the means of its mini-batches' terms; with ``target_kl``, the update stops
    at the first mini-batch whose KL passes 1.5 times it (SB3's rule) and reports the ones before."""
    env = make_vec(num_envs=16).unwrapped
    hyper, _, _ = small_config().resolve()
    observations = env.reset_tensors(0)
    generator = torch.Generator().manual_seed(0)
    advantages, returns = torch.randn(2, 16, generator=generator), torch.randn(2, 16, generator=generator)
    seen = []

    def recording(policy, batch, settings, clip_range):
        loss, terms = batched_ppo.minibatch_loss(policy, batch, settings, clip_range)
        seen.append({name: float(value.detach()) for name, value in terms.items()})
        return loss, terms

    def update(target_kl):
        model = batched_ppo.build_learner(hyper, env.template, 0)
        with torch.no_grad():
            actions, values, log_probs = model.policy(observations)
        rollout = batched_ppo.Rollout.empty(2, 16, observations.shape[1], 4, "cpu")
        rollout.observations[:], rollout.actions[:], rollout.log_probs[:] = observations, actions.float(), log_probs
        rollout.values[:], rollout.advantages, rollout.returns = values.flatten(), advantages, returns
        settings = dataclasses.replace(
            batched_ppo.RolloutSettings.of(model), n_epochs=2, batch_size=8, target_kl=target_kl
        )
        seen.clear()
        return batched_ppo.update(model, rollout, settings, 0.2, recording)

    stats = update(target_kl=None)
    assert len(seen) == 8  # 32 samples in mini-batches of 8, twice
    for name in batched_ppo.TERMS:
        assert stats[name] == pytest.approx(sum(terms[name] for terms in seen) / len(seen), rel=1e-6, abs=1e-9)
    stats = update(target_kl=1e-9)  # the first mini-batch is the rollout's own policy (KL 0), the second is not
    assert len(seen) == 2
    assert stats == pytest.approx(seen[0], rel=1e-6, abs=1e-9)


def test_the_loop_compiles_its_loss_with_a_tanh_within_rounding_of_torchs(monkeypatch):
    """``compile=True`` compiles the loss with LOSS_COMPILE_OPTIONS, where inductor's CPU code computes tanh from exp
    (several times faster than its own tanh): within 2e-7 of torch's, its ends, its smallest values and NaN too."""
    x = torch.cat([torch.linspace(-20, 20, 4001), torch.tensor([1e-30, -1e-7, 1e-3, math.inf, -math.inf, math.nan])])
    compiled = torch.compile(lambda values: torch.tanh(values), options=batched_ppo.LOSS_COMPILE_OPTIONS)
    torch.testing.assert_close(compiled(x), torch.tanh(x), rtol=0, atol=2e-7, equal_nan=True)
    asked = []
    monkeypatch.setattr(batched_ppo.torch, "compile", lambda function, **options: asked.append(options) or function)
    env = make_vec(num_envs=4).unwrapped
    model = batched_ppo.build_learner(small_config().resolve()[0], env.template, 0)
    batched_ppo.learn(model, env, 32, seed=0, compile=True)
    assert asked == [{"options": batched_ppo.LOSS_COMPILE_OPTIONS}]


def test_the_compiled_loss_is_the_eager_loss():
    """``dpr train --engine batched --compile`` compiles the mini-batch loss: the same loss, parts and gradients."""
    env = make_vec(num_envs=16).unwrapped
    hyper, _, _ = small_config().resolve()
    model = batched_ppo.build_learner(hyper, env.template, 0)
    settings = batched_ppo.RolloutSettings.of(model)
    generator = torch.Generator().manual_seed(0)
    observations = env.reset_tensors(0)
    batch = (
        observations,
        torch.randint(0, 2, (16, 4), generator=generator).float(),
        -torch.rand(16, generator=generator) * 3,
        torch.randn(16, generator=generator),
        torch.randn(16, generator=generator),
        *model.policy.observation_parts(observations),  # as the loop gives them to the swarm policy
    )

    def loss_and_gradients(loss_of):
        model.policy.optimizer.zero_grad()
        loss, terms = loss_of(model.policy, batch, settings, torch.tensor(0.2))
        loss.backward()
        return loss.detach(), terms, [weight.grad.clone() for weight in model.policy.parameters()]

    eager = loss_and_gradients(batched_ppo.minibatch_loss)
    # dynamo's graph and AOTAutograd's backward, as the loop compiles them; inductor's kernels (a C++ build of tens of
    # seconds on a bare machine) stand in for eager ones
    loss_of = torch.compile(batched_ppo.minibatch_loss, backend="aot_eager")
    compiled = loss_and_gradients(loss_of)
    torch.testing.assert_close(compiled[0], eager[0])
    for name, value in eager[1].items():
        torch.testing.assert_close(compiled[1][name].detach(), value, msg=name)
    for mine, theirs in zip(compiled[2], eager[2]):
        torch.testing.assert_close(mine, theirs, rtol=1e-4, atol=1e-6)
    # the updates give the clip range as a tensor: a schedule's next value runs the same compiled graph
    rollout = batched_ppo.Rollout.empty(2, 16, observations.shape[1], 4, "cpu")
    rollout.observations[:] = observations
    rollout.advantages, rollout.returns = (
        torch.randn(2, 16, generator=generator),
        torch.randn(2, 16, generator=generator),
    )
    one_epoch = dataclasses.replace(settings, n_epochs=1)
    batched_ppo.update(model, rollout, one_epoch, 0.2, loss_of)
    graphs = torch._dynamo.utils.counters["stats"]["unique_graphs"]
    batched_ppo.update(model, rollout, one_epoch, 0.1, loss_of)
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == graphs


@pytest.mark.parametrize("learner", ["torch", "sb3"])
def test_a_batched_run_keeps_the_threads_torch_was_given(tmp_path, learner):
    """The pymunk runs train on one thread beside one env process per core; the batched engine steps every swarm
    in one call, so its runs keep the process's threads."""
    given = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        train_batched(small_config(learner=learner), tmp_path / "run", **QUIET)
        assert torch.get_num_threads() == 2
        assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["torch_threads"] == 2
    finally:
        torch.set_num_threads(given)


def test_dpr_train_engine_batched_resume_needs_a_snapshot(tmp_path, capsys):
    argv = ["train", "--algo", "ppo", "--env", NAV, "--engine", "batched", "--robot-model", "disk", "--resume"]
    with pytest.raises(SystemExit):
        main([*argv, "--out", str(tmp_path / "none")])
    assert "holds no snapshot of a stopped batched run" in capsys.readouterr().err


def test_dpr_train_learner_sb3_trains_any_algorithm_on_the_batched_engine(tmp_path):
    argv = ["train", "--algo", "a2c", "--env", NAV, "--engine", "batched", "--learner", "sb3", "--robot-model", "disk"]
    out = tmp_path / "a2c"
    assert main([*argv, "--n-robots", "4", "--n-envs", "4", "--timesteps", "80", "--out", str(out)]) == 0
    record = (out / "config.yaml").read_text()
    assert "learner: sb3" in record and "engine: batched" in record and (out / "model.zip").is_file()
    checkpoints = sorted((out / "checkpoints").iterdir(), key=lambda path: int(path.stem.split("_")[1]))
    assert [path.name for path in checkpoints] == [f"model_{steps}_steps.zip" for steps in (20, 40, 60, 80)]
    assert load_model(checkpoints[0])[1].env_id == NAV  # each a model file that dpr evaluate runs
    with pytest.raises(ParameterError, match="learner"):
        small_config(engine="pymunk", learner="sb3")


def test_dpr_train_engine_batched_takes_the_disk_model_unless_told_otherwise(tmp_path, capsys):
    argv = ["train", "--algo", "ppo", "--env", NAV, "--engine", "batched", "--n-robots", "4", "--n-envs", "4"]
    hyper = ["--hyperparam", "n_steps=8", "--hyperparam", "batch_size=32"]
    assert main([*argv, *hyper, "--timesteps", "32", "--out", str(tmp_path / "run")]) == 0
    assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["env_kwargs"]["robot_model"] == "disk"
    with pytest.raises(SystemExit):
        main([*argv, "--robot-model", "paddle", "--out", str(tmp_path / "paddle")])
    assert "the batched engine has the disk model only: 'paddle'" in capsys.readouterr().err
    assert not (tmp_path / "paddle").exists()


def test_models_move_between_engines_through_the_commands(tmp_path):
    out = tmp_path / "batched"
    argv = ["train", "--algo", "ppo", "--env", NAV, "--engine", "batched", "--robot-model", "disk", "--n-envs", "4"]
    hyper = ["--hyperparam", "n_steps=8", "--hyperparam", "batch_size=32"]
    assert main([*argv, "--n-robots", "4", *hyper, "--timesteps", "32", "--out", str(out)]) == 0
    scores = {}
    for name, policy, engine, extra in (
        ("trained-batched-on-pymunk", out / "model.zip", "pymunk", []),
        ("shipped-pymunk-on-batched", REPO / "models" / "navigation-ppo.zip", "batched", ["--robot-model", "disk"]),
    ):
        path = tmp_path / f"{name}.json"
        command = ["evaluate", "--policy", str(policy), "--env", NAV, "--seeds", "2-3", "--steps", "30"]
        assert main([*command, "--engine", engine, *extra, "--json", str(path)]) == 0
        scores[name] = json.loads(path.read_text())
    assert [e["steps"] for e in scores["trained-batched-on-pymunk"]["episodes"]] == [30, 30]  # physics steps
    assert scores["trained-batched-on-pymunk"]["env_kwargs"]["action_repeat"] == 6  # the batched entry's
    assert scores["shipped-pymunk-on-batched"]["env_kwargs"]["robot_model"] == "disk"

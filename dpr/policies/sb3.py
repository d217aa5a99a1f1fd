"""stable-baselines3 models: building them, saving and loading them, and running them as policies.

This is the one place that makes SB3 models, below both :mod:`dpr.imitation` (behaviour cloning trains a model
built here) and :mod:`dpr.rl` (training and fine-tuning): the model a :class:`dpr.policies.hyperparams.Hyperparams`
describes, which parameters are the actor's, copying an initial policy in, and saving and loading model files (what
a model file says about how it was trained is :mod:`dpr.policies.model_file`'s).

stable-baselines3 and torch are imported inside functions only: the scripted policies (and everything that
imports this package) must not pay for them.
"""

from __future__ import annotations

import functools
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dpr.checks import ParameterError
from dpr.policies.model_file import (
    A2C,
    ALGOS,
    MODEL_SUFFIX,
    POLICY_PARAMETER,
    PPO,
    SPACE_KWARGS,
    SWARM_POLICY,
    SWARM_POLICY_MODULE,
    ModelInfo,
    check_model_members,
    read_model_info,
    write_model_info,
)

FINETUNE_ALGOS = (PPO, A2C)  # actor-critics: a cloned action distribution goes on training under them
BC_ALGOS = ALGOS  # actor-critics (an action distribution) and DQN (Q-values as logits)
DEFAULT_ALGO = PPO
# The TrainConfig field that names the model a fine-tuning run starts from (dpr.rl.train).
INIT_PARAMETER = "init_from"
# The value head of an actor-critic policy: what the actor's parameters are not.
VALUE_HEAD_PREFIXES = ("mlp_extractor.value_net.", "value_net.", "vf_features_extractor.")


def loaded_architecture(path: str | Path) -> dict[str, Any] | None:
    """The network of the model file at ``path``, read off the loaded model, for files that do not record it
    (:attr:`ModelInfo.architecture`): a SwarmPolicy or SB3's MlpPolicy whose policy_kwargs are plain data (the
    ``has_object`` flag and ``landmarks`` count the builder adds left out); None for any other."""
    model, _ = load_model(path)
    if type(model.policy).__module__ == SWARM_POLICY_MODULE:
        policy = SWARM_POLICY
    elif type(model.policy).__name__ == "ActorCriticPolicy":
        policy = "MlpPolicy"
    else:
        return None
    layout = ("has_object", "landmarks")  # what the builder reads off the env
    kwargs = {name: value for name, value in (model.policy_kwargs or {}).items() if name not in layout}
    if not all(isinstance(value, (bool, int, float, str, list, dict)) for value in kwargs.values()):
        return None
    return {"policy": policy, "policy_kwargs": kwargs}


def algo_class(algo: str):
    """The SB3 class of ``algo`` ("ppo", "a2c" or "dqn")."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def describe_space(space) -> str:
    """A space in one short line (a Box's repr lists every bound)."""
    shape = getattr(space, "shape", None)
    if type(space).__name__ == "Box":
        return f"Box(shape={shape}, dtype={space.dtype})"
    return str(space)


def _differing_space_kwargs(info: ModelInfo, env) -> dict[str, tuple[Any, Any]]:
    """The :data:`SPACE_KWARGS` the model was trained with that ``env`` (a gymnasium env) sets otherwise: name ->
    (the model's value, the env's). Empty for a VecEnv, which does not say."""
    base = getattr(env, "unwrapped", None)
    return {
        name: (info.env_kwargs[name], getattr(base, name))
        for name in SPACE_KWARGS
        if name in info.env_kwargs and hasattr(base, name) and getattr(base, name) != info.env_kwargs[name]
    }


def _space_mismatch(path: Path, info: ModelInfo, model, env) -> str | None:
    """A sentence on why ``model`` cannot act in ``env``, or None when the spaces agree."""
    problems = []
    if model.observation_space != env.observation_space:
        model_space, env_space = describe_space(model.observation_space), describe_space(env.observation_space)
        problems.append(f"observation space {model_space} vs the env's {env_space}")
    if model.action_space != env.action_space:
        problems.append(
            f"action space {describe_space(model.action_space)} vs the env's {describe_space(env.action_space)}"
        )
    if not problems:
        return None
    differing = [
        f"{name}={ours!r} (the env has {name}={theirs!r})"
        for name, (ours, theirs) in _differing_space_kwargs(info, env).items()
    ]
    trained = f"; it was trained with {', '.join(differing)}" if differing else ""
    return f"model {path} does not fit this env: {'; '.join(problems)}{trained}"


def _swarm_model_resized(model, env):
    """The :data:`SWARM_POLICY` ``model`` acting in ``env``, another swarm size than its own. Its actor is one
    network shared by the robots, so the same weights act for any N; so does the swarm critic, whereas the MLP
    critic reads the whole state of N robots and is not carried over: the model acts, it does not train."""
    policy = model.policy
    params = policy._get_constructor_parameters()
    params.update(observation_space=env.observation_space, action_space=env.action_space)
    resized = type(policy)(**params)
    _load_weights(resized, policy.state_dict(), with_critic=_critic_of(policy) == "swarm")
    model.policy = resized
    model.observation_space, model.action_space = env.observation_space, env.action_space
    return model


def load_model(
    path: str | Path, env=None, *, for_training: bool = False, parameter: str = POLICY_PARAMETER, transfer: bool = False
):
    """The SB3 model at ``path`` and its :class:`ModelInfo`, checked against ``env`` (a gymnasium env: its id
    and spaces; or a VecEnv: its spaces) when one is given. Nothing in the file is unpickled
    (:func:`model_objects`). With ``for_training`` the model's schedules are restored from the file's plain values
    and ``env`` is attached, ready for ``learn``; otherwise they are constants (prediction does not use them). A
    file that is no model, or holds a pickled entry no dpr model holds, is a :class:`ParameterError` about
    ``parameter`` (see :func:`read_model_info`). With ``transfer`` the env may be another task's (its spaces are
    still checked)."""
    path = Path(path)
    info = read_model_info(path, parameter)
    env_id = getattr(getattr(env, "spec", None), "id", None)
    if env_id is not None and env_id != info.env_id and not transfer:
        raise ValueError(f"model {path} was trained on {info.env_id}; this env is {env_id}")
    from dpr.policies.model_objects import model_objects

    custom = model_objects(path, info, for_training, parameter)
    try:
        with zipfile.ZipFile(path) as archive:  # every member SB3 reads, within its bound, before it reads them
            check_model_members(archive, path, parameter, stream=True)
    except zipfile.BadZipFile as error:
        raise ParameterError(parameter, f"{path} is not a readable .zip model file ({error})") from None
    model = _sb3_load(path, info, parameter, custom_objects=custom)
    if env is not None:
        per_robot_parallel = False
        if info.per_robot is not None:  # its spaces are one robot's: the env must give local observations
            from dpr.policies.per_robot_spec import check_per_robot_env

            check_per_robot_env(path, info, env, centralised=False)
            per_robot_parallel = not hasattr(env, "parallel_env")  # a PettingZoo env: spaces per agent
        # Spaces are compared here rather than by SB3's load(env=...), so that the error names the env kwargs.
        mismatch = None if per_robot_parallel else _space_mismatch(path, info, model, env)
        if (
            mismatch
            and set(_differing_space_kwargs(info, env)) == {"n_robots"}
            and type(model.policy).__module__ == SWARM_POLICY_MODULE  # loaded: no need to read the file again
        ):
            if for_training:
                raise ValueError(
                    f"{mismatch}. A {SWARM_POLICY} model acts at any swarm size but trains only at its own: "
                    "its critic reads the whole state"
                )
            model, mismatch = _swarm_model_resized(model, env), None
        if mismatch:
            raise ValueError(mismatch)
        if for_training and info.algo not in FINETUNE_ALGOS:
            raise ValueError(f"model {path} is a {info.algo} model; dpr trains further only {FINETUNE_ALGOS}")
        if for_training and per_robot_parallel:
            raise ValueError(f"per-robot model {path} trains on the agents' VecEnv: AgentsAsVecEnv(env)")
        if for_training and info.per_robot is not None and env.num_envs != model.n_envs:
            # One VecEnv entry per robot: another swarm size is another n_envs, which set_env refuses and SB3's
            # load rebuilds the rollout buffer for.
            model = _sb3_load(path, info, parameter, env=env, custom_objects=custom)  # (checked above)
        elif for_training:
            model.set_env(env)
    return model, info


def _sb3_load(path: Path, info: ModelInfo, parameter: str, **options):
    """SB3's load of the model file at ``path``; one that cannot be loaded is a :class:`ParameterError` about
    ``parameter`` naming it, and a weights member holding a pickle that is more than weights (which torch refuses)
    is said without torch's advice to load it with ``weights_only=False``."""
    import pickle

    from dpr.policies.torch_files import is_refused_pickle, refused_pickle

    try:
        return algo_class(info.algo).load(path, device="cpu", **options)
    except (
        KeyError,
        ValueError,
        RuntimeError,
        TypeError,
        zipfile.BadZipFile,
        EOFError,
        pickle.UnpicklingError,
    ) as error:
        if is_refused_pickle(error):
            problem = f"its weights hold {refused_pickle(error)}; refused, nothing in it was run"
            raise ParameterError(parameter, f"{path}: {problem}") from None
        raise ParameterError(parameter, f"cannot load {info.algo} model {path}: {error}") from None


class ModelPolicy:
    """A trained model as a ``policy(observation) -> action`` callable: deterministic actions, so ``reset(seed)``
    has nothing to reseed."""

    def __init__(self, model, info: ModelInfo, path: Path):
        self.model = model
        self.info = info
        self.path = path

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy is a pure function of the observation."""

    def __call__(self, observation):
        action, _ = self.model.predict(observation, deterministic=True)
        return action


def single_thread_torch() -> None:
    """One torch thread in this process. The networks are small MLPs, which more threads do not speed up;
    envs and evaluation run one process per core, and torch's spinning worker threads competing with them
    slowed training and evaluation down tenfold and more on 2 cores."""
    import torch

    torch.set_num_threads(1)


def load_model_policy(path: str | Path, env, transfer: bool = False) -> ModelPolicy:
    """The model file at ``path`` as a policy for ``env`` (ValueError when it was made for another env, but with
    ``transfer`` for another task with its spaces),
    predicting on one torch thread (:func:`single_thread_torch`). A per-robot model is refused here: it acts in
    a centralised env through :func:`dpr.policies.per_robot_model.per_robot_model_policy` (what
    :func:`dpr.policies.registry.make_policy` returns for it)."""
    single_thread_torch()
    model, info = load_model(path, env, transfer=transfer)
    return ModelPolicy(model, info, Path(path))


# ------------------------------------------------------------------------------------------------ building


def make_env_fn(env_id: str, env_kwargs: dict[str, Any], steps: int) -> Callable[[], Any]:
    """A factory of one Monitor-wrapped env that logs its episode for a resume (:class:`dpr.envs.replay.ReplayLog`;
    picklable; registers the ids in a fresh process)."""

    def make():
        import gymnasium as gym
        from stable_baselines3.common.monitor import Monitor

        import dpr  # noqa: F401
        from dpr.envs.replay import ReplayLog

        return Monitor(ReplayLog(gym.make(env_id, max_episode_steps=steps, **env_kwargs)))

    return make


def make_vec_env(
    env_id: str,
    env_kwargs: dict[str, Any],
    steps: int,
    n_envs: int,
    episodes: list[dict | None] | None = None,
    processes: bool = True,
):
    """``n_envs`` envs in subprocesses (forked: cheap, and the ids are already registered), or in this
    process when there is one or ``processes`` is False; with ``episodes`` (a resumed run's ReplayLog records, one
    per env) each env is brought back to where its episode stood (:func:`dpr.envs.replay.replay`)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from dpr.envs.replay import replay

    if episodes is not None and len(episodes) != n_envs:
        raise ValueError(f"{len(episodes)} episodes to replay for {n_envs} envs")
    fns = [make_env_fn(env_id, env_kwargs, steps) for _ in range(n_envs)]
    if episodes is not None:
        fns = [functools.partial(replay, fn, episode) for fn, episode in zip(fns, episodes, strict=True)]
    if n_envs > 1 and processes:
        return SubprocVecEnv(fns, start_method="fork")
    return DummyVecEnv(fns)


def build_model(hyper, env, seed: int, tensorboard_log: str | None, single_thread: bool = True):
    """The SB3 model that ``hyper`` (a :class:`dpr.policies.hyperparams.Hyperparams`) describes, on ``env`` (a
    VecEnv), seeded with ``seed``: what ``dpr train`` trains and what ``dpr bc`` clones into. Its initial weights
    follow from the torch RNG state, ``hyper`` and ``seed`` alone. It trains on one torch thread
    (``single_thread``; the batched engine keeps its threads)."""
    if single_thread:
        single_thread_torch()
    kwargs = hyper.model_kwargs(n_robots=env.get_attr("n_robots")[0])
    policy = hyper.policy
    if policy == SWARM_POLICY:
        from dpr.policies.swarm_policy import SwarmActorCriticPolicy

        policy = SwarmActorCriticPolicy
        layout = {"has_object": env.get_attr("has_object")[0], "landmarks": len(env.get_attr("landmark_names")[0])}
        kwargs["policy_kwargs"] = {**kwargs.get("policy_kwargs", {}), **layout}
    return algo_class(hyper.algo)(
        policy, env, seed=seed, verbose=0, device="cpu", tensorboard_log=tensorboard_log, **kwargs
    )


def check_hyperparameters(hyper, env, seed: int) -> None:
    """Build ``hyper``'s model once on ``env`` (one env, not vectorised) so that SB3's own checks of the values
    (``n_steps * n_envs > 1``, a batch size that fits...) fail as a ParameterError before any work starts."""
    import warnings

    from stable_baselines3.common.vec_env import DummyVecEnv

    try:
        with warnings.catch_warnings():  # about mini-batches of this one env's rollouts, not of the run's n_envs
            warnings.filterwarnings("ignore", message="You have specified a mini-batch size")
            build_model(hyper, DummyVecEnv([lambda: env]), seed, None)
    except (AssertionError, ValueError, TypeError) as error:
        raise ParameterError("hyperparams", f"{hyper.algo} refuses them: {error}") from None


def actor_parameters(policy) -> list:
    """The parameters that decide the action distribution: everything but the value head."""
    return [p for name, p in policy.named_parameters() if not name.startswith(VALUE_HEAD_PREFIXES)]


def trained_parameters(policy) -> list:
    """What BC trains: an actor-critic's actor, or a DQN policy's Q-network (its target is copied after)."""
    if hasattr(policy, "q_net"):
        return list(policy.q_net.parameters())
    return actor_parameters(policy)


def check_initial_spaces(path: str | Path, source, info: ModelInfo, target, parameter: str = INIT_PARAMETER) -> None:
    """A :class:`ParameterError` about ``parameter`` naming the model file at ``path`` (loaded as ``source``, with
    ``info``) when its observation or action space is not ``target``'s (a model or an env to train on)."""
    for name in ("observation_space", "action_space"):
        if getattr(source, name) != getattr(target, name):
            kind = (
                "; it is a per-robot model (one robot's local observation): it trains on "
                "AgentsAsVecEnv(parallel_env(..., local_obs=True)), not on the centralised env"
                if info.per_robot is not None
                else ""
            )
            raise ParameterError(
                parameter,
                f"{path}: its {name} {describe_space(getattr(source, name))} differs from "
                f"this run's {describe_space(getattr(target, name))} (env kwargs {info.env_kwargs}){kind}",
            )


def load_initial_policy(model, path: str | Path, parameter: str = INIT_PARAMETER) -> None:
    """Copy the policy weights of the model file at ``path`` into ``model`` (same spaces and network).
    A :class:`ParameterError` about ``parameter`` (the caller's name for ``path``; ``init_from`` of
    :class:`dpr.rl.train.TrainConfig` by default) naming the file when they do not fit."""
    source, info = load_model(path, parameter=parameter)
    check_initial_spaces(path, source, info, model, parameter)
    try:
        # another critic: e.g. a clone (whose value head BC never trained) fine-tuned with the swarm critic
        _load_weights(model.policy, source.policy.state_dict(), _critic_of(source.policy) == _critic_of(model.policy))
    except RuntimeError as error:
        raise ParameterError(
            parameter,
            f"{path} ({info.algo}) has another network than this run's "
            f"{model.policy.net_arch}: {str(error).splitlines()[0]}",
        ) from None


def _load_weights(policy, weights: dict, with_critic: bool) -> None:
    """Load ``weights`` (a state dict) into ``policy``: all of them, or without the value head, which then keeps its
    own initialisation. A RuntimeError naming the weights that do not fit."""
    if with_critic:
        policy.load_state_dict(weights)
        return
    actor = {name: value for name, value in weights.items() if not name.startswith(VALUE_HEAD_PREFIXES)}
    missing, unexpected = policy.load_state_dict(actor, strict=False)
    if unexpected or not all(name.startswith(VALUE_HEAD_PREFIXES) for name in missing):
        raise RuntimeError(f"the actor's weights do not fit: {missing + unexpected}")


def _critic_of(policy) -> str:
    """Which critic a policy has: ``mlp`` unless it is a :data:`SWARM_POLICY` built with the swarm critic."""
    return getattr(policy, "critic", "mlp")


def save_slim_copy(source: str | Path, target: str | Path, average_with: Sequence[str | Path] = ()) -> Path:
    """Copy the model file ``source`` to ``target`` without the optimizer's running moments, which nothing
    reads back (fine-tuning and evaluation load the weights only): a PPO file shrinks to about a third. With
    ``average_with`` (model files of the same network, e.g. the checkpoints of ``source``'s run), the copy's weights
    are the mean of theirs and ``source``'s: weight averaging along a run. ``target`` appears once it is complete."""
    model, info = load_model(source)
    policy = model.policy
    if average_with:
        states = [policy.state_dict(), *(load_model(other)[0].policy.state_dict() for other in average_with)]
        mean = {name: sum(state[name] for state in states) / len(states) for name in states[0]}
        policy.load_state_dict(mean)
    learning_rate = policy.optimizer.param_groups[0]["lr"]
    policy.optimizer = policy.optimizer_class(policy.parameters(), lr=learning_rate, **policy.optimizer_kwargs)
    target = Path(target)
    partial = target.with_name(f".{target.stem}.partial{MODEL_SUFFIX}")
    save_model(model, partial, info)
    return partial.replace(target)


def save_model(model, path: str | Path, info: ModelInfo) -> Path:
    """Save ``model`` to ``path`` (a ``.zip`` file, replaced if present; its folder made) with ``info`` inside it."""
    path = Path(path)
    if path.suffix != MODEL_SUFFIX:
        raise ValueError(f"model path must end in {MODEL_SUFFIX}, got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)  # (SB3 would make it too, with a warning amid the progress bar)
    model.save(path)  # a fresh zip: any metadata of an older file at this path is gone with it
    write_model_info(path, info)
    return path

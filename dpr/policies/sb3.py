"""stable-baselines3 models: building them, saving and loading them, and running them as policies.

This is the one place that makes SB3 models, below both :mod:`dpr.imitation` (behaviour cloning trains a model
built here) and :mod:`dpr.rl` (training and fine-tuning): the algorithm names, the model a
:class:`dpr.policies.hyperparams.Hyperparams` describes, which parameters are the actor's, copying an initial
policy in, and the model files.

A model file is SB3's own zip plus one small JSON member, :data:`METADATA_MEMBER`, that names the algorithm,
the env id and the env kwargs the model was trained with, so that a model can be evaluated or rolled out
without restating them, and the network it was built with, so that fine-tuning builds the same. A per-robot
model (one robot's local observation in, that robot's action out, for any swarm size;
:mod:`dpr.policies.per_robot_spec`) also carries its local-observation layout there.
stable-baselines3 and torch are imported inside functions only: the scripted policies (and everything that
imports this package) must not pay for them.
"""

from __future__ import annotations

import functools
import json
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from dpr.bounded_io import read_zip_member, stream_zip_member
from dpr.checks import ParameterError
from dpr.limits import MAX_MODEL_JSON_BYTES, MAX_MODEL_MEMBER_BYTES

MODEL_SUFFIX = ".zip"
METADATA_MEMBER = "dpr_env.json"
METADATA_FORMAT = 1
PPO, A2C, DQN = "ppo", "a2c", "dqn"
ALGOS = (PPO, A2C, DQN)  # the SB3 algorithms a model file may hold (`dpr train`)
FINETUNE_ALGOS = (PPO, A2C)  # actor-critics: a cloned action distribution goes on training under them
BC_ALGOS = ALGOS  # actor-critics (an action distribution) and DQN (Q-values as logits)
DEFAULT_ALGO = PPO
# A hyperparameter entry's `policy`: SB3's own names, or the shared per-robot actor (dpr.policies.swarm_policy).
SWARM_POLICY = "SwarmPolicy"
SWARM_POLICY_MODULE = "dpr.policies.swarm_policy"  # where it is defined, as a model file names it
# The parameter that names a model file in evaluate and collect: what a bad model file is reported as by default.
POLICY_PARAMETER = "policy"
# The TrainConfig field that names the model a fine-tuning run starts from (dpr.rl.train).
INIT_PARAMETER = "init_from"
# The value head of an actor-critic policy: what the actor's parameters are not.
VALUE_HEAD_PREFIXES = ("mlp_extractor.value_net.", "value_net.", "vf_features_extractor.")
# Env kwargs whose value decides the observation or action space: a different value can never run the model.
SPACE_KWARGS = ("n_robots", "action_type", "obs_type", "obs_last_action", "image_size")
# Env kwargs a centralised model may be run with otherwise than it was trained: the two robot models make the same
# observation and action spaces (sim-to-sim transfer, e.g. from the faster disk model to the paddle model).
TRANSFERABLE_KWARGS = ("robot_model",)


def is_model_path(name: str) -> bool:
    """Whether a policy name (``--policy``) is a model file rather than a scripted policy."""
    return name.endswith(MODEL_SUFFIX)


@dataclass(frozen=True)
class ModelInfo:
    """What a model file says about how it was trained (the :data:`METADATA_MEMBER` of its zip)."""

    algo: str
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    max_episode_steps: int | None = None
    # A per-robot model's layout and training swarm (dpr.policies.per_robot_spec.RobotModelSpec as data);
    # None for a model of the centralised env, whose observation is the whole swarm's state.
    per_robot: dict[str, Any] | None = None
    # The network it was built with, as its yaml entry says it (:func:`model_architecture`): what a fine-tuning run
    # must build to load its weights. None in files written before it was recorded, and in per-robot models.
    architecture: dict[str, Any] | None = None

    def as_json(self) -> str:
        data = asdict(self)
        for name in ("per_robot", "architecture"):  # files without them stay as they were
            if data[name] is None:
                del data[name]
        return json.dumps({"format": METADATA_FORMAT, **data}, indent=2, sort_keys=True)


def model_architecture(hyper) -> dict[str, Any]:
    """The network that ``hyper`` (a :class:`dpr.policies.hyperparams.Hyperparams`) builds, in yaml form:
    ``{"policy": "SwarmPolicy", "policy_kwargs": {...}}`` (the entry's policy name and its policy_kwargs, {} when it
    sets none): :attr:`ModelInfo.architecture`, and the hyperparameter overrides that build it again."""
    return {"policy": str(hyper.policy), "policy_kwargs": dict(hyper.algo_kwargs.get("policy_kwargs") or {})}


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


def _checked_architecture(value: Any) -> dict[str, Any] | None:
    """``value`` as :attr:`ModelInfo.architecture` (None when absent); a ValueError saying what is wrong with it."""
    if value is None:
        return None
    if (
        not isinstance(value, dict)
        or set(value) != {"policy", "policy_kwargs"}
        or not isinstance(value["policy"], str)
        or not isinstance(value["policy_kwargs"], dict)
    ):
        raise ValueError(f"architecture must be a mapping of a policy name and its policy_kwargs, got {value!r}")
    return {"policy": value["policy"], "policy_kwargs": dict(value["policy_kwargs"])}


def algo_class(algo: str):
    """The SB3 class of ``algo`` ("ppo", "a2c" or "dqn")."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def write_model_info(path: str | Path, info: ModelInfo) -> None:
    """Append ``info`` to the SB3 zip at ``path`` (SB3's loader ignores members it does not know)."""
    algo_class(info.algo)  # validates the name before anything is written
    with zipfile.ZipFile(path, "a") as archive:
        if METADATA_MEMBER in archive.namelist():
            raise ValueError(f"{path} already holds {METADATA_MEMBER}; save the model to a new file first")
        archive.writestr(METADATA_MEMBER, info.as_json())


def model_member_limit(name: str) -> int | None:
    """The most bytes dpr or stable-baselines3 reads of the model zip member ``name`` (None: never read)."""
    if name in ("data", METADATA_MEMBER, "_stable_baselines3_version"):
        return MAX_MODEL_JSON_BYTES
    return MAX_MODEL_MEMBER_BYTES if name.endswith(".pth") else None


def check_model_members(archive: zipfile.ZipFile, path: str | Path, parameter: str, *, stream: bool = False) -> None:
    """A :class:`ParameterError` about ``parameter`` when a member of the model zip that is read declares more bytes
    than :func:`model_member_limit`; with ``stream``, each is also read through (a chunk at a time) to check that it
    inflates to what it declares, and its CRC, before stable-baselines3 reads it whole."""
    for info in archive.infolist():
        limit = model_member_limit(info.filename)
        if limit is None:
            continue
        if stream:
            for _ in stream_zip_member(archive, info.filename, limit, path, parameter):
                pass
        elif info.file_size > limit:
            raise ParameterError(
                parameter, f"{path}: its member {info.filename!r} declares {info.file_size} bytes, more than {limit}"
            )


def read_model_info(path: str | Path, parameter: str = POLICY_PARAMETER) -> ModelInfo:
    """The :class:`ModelInfo` of the model file at ``path``; a :class:`ParameterError` about ``parameter`` (the
    caller's parameter that named the file) when the file is missing, not a zip, or not a ``dpr train`` model."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError(parameter, f"no model file at {path}")
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "data" not in names:
                raise ParameterError(parameter, f"{path} is a zip but not a stable-baselines3 model (no 'data' member)")
            if METADATA_MEMBER not in names:
                raise ParameterError(
                    parameter,
                    f"{path} is an SB3 model without {METADATA_MEMBER}, so its env id and env kwargs are "
                    "unknown; use a model saved by `dpr train` (dpr.policies.sb3.save_model)",
                )
            check_model_members(archive, path, parameter)
            raw = read_zip_member(archive, METADATA_MEMBER, MAX_MODEL_JSON_BYTES, path, parameter)
    except zipfile.BadZipFile as error:
        raise ParameterError(parameter, f"{path} is not a readable .zip model file ({error})") from None
    try:
        data = json.loads(raw)
        info = ModelInfo(
            algo=data["algo"],
            env_id=data["env_id"],
            env_kwargs=dict(data["env_kwargs"]),
            max_episode_steps=data.get("max_episode_steps"),
            per_robot=None if data.get("per_robot") is None else dict(data["per_robot"]),
            architecture=_checked_architecture(data.get("architecture")),
        )
    except (ValueError, KeyError, TypeError) as error:
        raise ParameterError(parameter, f"{path}: {METADATA_MEMBER} is malformed ({error!r})") from None
    if info.algo not in ALGOS:
        raise ParameterError(
            parameter, f"{path}: unknown algo {info.algo!r} in {METADATA_MEMBER}; expected one of {ALGOS}"
        )
    return info


def _drives_any_task_like(info: ModelInfo, env_id: str) -> bool:
    """Whether a per-robot model of ``info`` runs on ``env_id``'s task too: its local observation has the same
    parts on every task with the same object or none (dpr.policies.per_robot_spec.check_per_robot_env)."""
    from dpr.envs import TASK_CLASSES, TASKS

    if info.per_robot is None or env_id not in TASKS or info.env_id not in TASKS:
        return False
    return TASK_CLASSES[TASKS[env_id]].has_object == TASK_CLASSES[TASKS[info.env_id]].has_object


def model_env_kwargs(
    path: str | Path, env_id: str, requested: dict[str, Any] | None = None, *, transfer: bool = False
) -> dict[str, Any]:
    """The env kwargs to run the model at ``path`` on ``env_id``: the model's own, plus any ``requested``
    kwargs it did not set. A requested value that differs from the model's is a ValueError naming both values,
    except ``n_robots`` for a :data:`SWARM_POLICY` model, which acts at any swarm size, and ``robot_model`` for a
    centralised model: the paddle and disk models share their spaces, so a policy learned on one runs on, and
    fine-tunes on, the other (:data:`TRANSFERABLE_KWARGS`). Another env id is a :class:`ParameterError` about
    ``env_id``, but for a per-robot model on a task with the same object or none, and with ``transfer``: a model
    run on another task as it is (zero-shot transfer; its spaces are checked when it is loaded for the env)."""
    info = read_model_info(path)
    if env_id != info.env_id and not (transfer or _drives_any_task_like(info, env_id)):
        raise ParameterError(
            "env_id",
            f"model {path} was trained on {info.env_id}; it cannot be run on {env_id} (unless as a transfer to "
            "another task with the same spaces: --transfer)",
        )
    kwargs = dict(info.env_kwargs)
    transferable = {"n_robots"} if has_swarm_actor(path) else set()  # its actor is shared by the robots: any N
    if info.per_robot is None:  # a per-robot model's local observation is laid out for its own robot model
        transferable.update(TRANSFERABLE_KWARGS)
    for name, value in (requested or {}).items():
        if name in kwargs and kwargs[name] != value and name not in transferable:
            why = (
                "makes a different observation or action space" if name in SPACE_KWARGS else "is not what it learned on"
            )
            only = f"; only a {SWARM_POLICY} model acts at any swarm size" if name == "n_robots" else ""
            raise ValueError(
                f"model {path} was trained with {name}={kwargs[name]!r}; {name}={value!r} {why} "
                f"(leave it out to use the model's value{only})"
            )
        kwargs[name] = value
    return kwargs


def describe_space(space) -> str:
    """A space in one short line (a Box's repr lists every bound)."""
    shape = getattr(space, "shape", None)
    if type(space).__name__ == "Box":
        return f"Box(shape={shape}, dtype={space.dtype})"
    return str(space)


def has_swarm_actor(path: str | Path) -> bool:
    """Whether the model file at ``path`` holds a :data:`SWARM_POLICY`, whose actor acts at any swarm size."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(read_zip_member(archive, "data", MAX_MODEL_JSON_BYTES, path, POLICY_PARAMETER))
    return data.get("policy_class", {}).get("__module__") == SWARM_POLICY_MODULE


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

"""Helpers shared by the test modules (tests/ is on sys.path under pytest's default import mode)."""

import contextlib
import hashlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

ENV_IDS = ("dpr/Navigation-v0", "dpr/Gate-v0", "dpr/Gate-v1", "dpr/Unresponsive-v0", "dpr/Manipulation-v0")
ROBOT_MODELS = ("paddle", "disk")
ACTION_TYPES = ("multibinary", "discrete", "continuous")
OBS_TYPES = ("state", "pixels", "pixels_state")


def robot_of_body(swarm) -> dict:
    """Map every body of ``swarm`` to the index of the robot it belongs to, by geometry at construction
    (a paddle lies within 40 units of its own robot's centre; robots start 77.5 apart)."""
    centres = np.array([tuple(b.position) for b in swarm.robot_bodies])
    owner = {}
    for body in swarm.bodies:
        d = np.linalg.norm(centres - np.array(tuple(body.position)), axis=1)
        owner[body] = int(np.argmin(d))
    return owner


def shift_robot(swarm, owner: dict, robot: int, offset) -> None:
    """Teleport every body of one robot by ``offset`` (velocities zeroed)."""
    offset = np.asarray(offset, dtype=float)
    for body, r in owner.items():
        if r == robot:
            body.position = tuple(np.array(tuple(body.position)) + offset)
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            if body.space is not None:
                body.space.reindex_shapes_for_body(body)


def move_bodies(bodies, offset) -> None:
    """Teleport ``bodies`` by ``offset`` and stop them."""
    offset = np.asarray(offset, dtype=float)
    for body in bodies:
        body.position = tuple(np.array(tuple(body.position)) + offset)
        body.velocity = (0.0, 0.0)
        body.angular_velocity = 0.0
        if body.space is not None:
            body.space.reindex_shapes_for_body(body)


def expansions(obs, n_robots: int) -> np.ndarray:
    """The expansion column of a state observation (or of a pixels_state dict)."""
    state = obs["state"] if isinstance(obs, dict) else obs
    return np.asarray(state)[: 6 * n_robots].reshape(n_robots, 6)[:, 5]


def positions(obs, n_robots: int) -> np.ndarray:
    state = obs["state"] if isinstance(obs, dict) else obs
    return np.asarray(state)[: 6 * n_robots].reshape(n_robots, 6)[:, 0:2]


def visited_observations(env, seeds=(0, 1, 2), steps=25) -> np.ndarray:
    """Observations of random rollouts: spread-out swarms at reset, then shuffled by random expansions."""
    out = []
    for seed in seeds:
        observation, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out.append(observation)
        for _ in range(steps):
            observation, *_ = env.step(env.action_space.sample())
            out.append(observation)
    return np.array(out)


def rotate_scene(
    observations: np.ndarray, n_robots: int, angle: float, object_at: int | None = None, landmarks: slice | None = None
) -> np.ndarray:
    """State observations of the same scene rotated by ``angle`` about the goal: every robot's position and
    velocity, the object's (its features at ``object_at``) when there is one, and the landmarks' positions (x, y
    pairs in ``landmarks``)."""
    c, s = np.cos(angle), np.sin(angle)
    rotated = observations.copy()
    pairs = [rotated[:, : 6 * n_robots].reshape(len(rotated), n_robots, 6)[..., i : i + 2] for i in (0, 2)]
    if object_at is not None:
        pairs += [rotated[:, object_at + i : object_at + i + 2] for i in (0, 2)]
    if landmarks is not None:
        pairs.append(rotated[:, landmarks].reshape(len(rotated), -1, 2))
    for pair in pairs:  # views into `rotated`
        x, y = pair[..., 0].copy(), pair[..., 1].copy()
        pair[..., 0], pair[..., 1] = c * x - s * y, s * x + c * y
    return rotated


def run_cli(argv: list[str]) -> int:
    """dpr.cli.main's exit status, whether it returns it or argparse raises SystemExit."""
    from dpr.cli import main

    try:
        return main(argv)
    except SystemExit as exit_:
        return exit_.code


def tree_hash(root: Path) -> str:
    """One hash of every folder's and file's name and every file's bytes under ``root``: equal before and after
    a refused command means it touched nothing."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        digest.update(str(path.relative_to(root)).encode() + b"\0")
        if path.is_file():
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def write_info(root: Path, info: dict, **dump) -> None:
    """Write a hand-edited ``info.json`` into the dataset at ``root``, sealed anew as the writer seals it when it
    carries meta checksums, so that a reader meets the edit itself rather than a checksum that no longer holds."""
    from dpr.datasets.lerobot.format import META_CHECKSUMS_KEY, sealed_info

    entry = info.get(META_CHECKSUMS_KEY)
    if entry is not None:
        plain = {key: value for key, value in info.items() if key != META_CHECKSUMS_KEY}
        info = sealed_info(plain, tasks=entry["tasks"], stats=entry["stats"], rows_from=entry["rows_from"])
    (root / "meta" / "info.json").write_text(json.dumps(info, **dump))


def write_stats(root: Path, stats: dict) -> None:
    """Write a hand-made ``stats.json`` into the dataset at ``root``, with its checksum in info.json where it
    keeps one: a stats.json a writer could have written, whose values the reader checks for themselves."""
    from dpr.datasets.lerobot.format import META_CHECKSUMS_KEY, content_digest

    (root / "meta" / "stats.json").write_text(json.dumps(stats))  # json writes inf as Infinity
    info = json.loads((root / "meta" / "info.json").read_text())
    if META_CHECKSUMS_KEY in info:
        info[META_CHECKSUMS_KEY]["stats"] = content_digest(json.loads((root / "meta" / "stats.json").read_text()))
        write_info(root, info, indent=4)


TOOLS = Path(__file__).resolve().parents[1] / "tools"


def load_tool(name: str):
    """The script ``tools/<name>.py`` as a module (scripts import their siblings, so tools/ is on the path while
    it loads)."""
    sys.path.insert(0, str(TOOLS))
    try:
        spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(TOOLS))
    return module


def assert_per_robot_model_acts_and_trains(model_path, n_robots: int) -> None:
    """A per-robot model file acts for every robot of a PettingZoo swarm of ``n_robots`` built from its own spec,
    and loads there as an SB3 model ready for PPO, one env per robot."""
    from dpr.envs.parallel import AgentsAsVecEnv, parallel_env
    from dpr.policies.model_file import read_model_info
    from dpr.policies.per_robot_model import RobotModelPolicy
    from dpr.policies.per_robot_spec import RobotModelSpec
    from dpr.policies.sb3 import load_model

    spec = RobotModelSpec.from_info(read_model_info(model_path), model_path)
    env = parallel_env("navigation", n_robots=n_robots, **spec.parallel_env_kwargs())
    observations, _ = env.reset(seed=2)
    actions = RobotModelPolicy.load(model_path).act_agents(observations)
    assert set(actions) == set(env.agents) and set(actions.values()) <= {0, 1}
    model, _ = load_model(model_path, AgentsAsVecEnv(env), for_training=True)
    assert model.get_env().num_envs == n_robots


def drive(env, policy, steps: int, seed: int) -> None:
    """Reset ``env`` and ``policy`` with ``seed`` and step ``steps`` times, asserting every action is in the action
    space; the env is closed."""
    observation, _ = env.reset(seed=seed)
    policy.reset(seed)
    try:
        for _ in range(steps):
            action = policy(observation)
            assert env.action_space.contains(action)
            observation, *_ = env.step(action)
    finally:
        env.close()


# One 32-step rollout per update, so that a few dozen steps of RL are a few updates, not a rollout of the yaml's 1024.
TINY_PPO = {"n_steps": 32, "batch_size": 32}
# PipelineConfig budgets of a pipeline run of seconds: 4 robots, two 30-step demonstrations, a few dozen steps of
# RL deciding every physics step on one env, in 32-step rollouts.
TINY_PIPELINE = dict(
    n_robots=4,
    steps=30,
    episodes=2,
    bc_epochs=1,
    critic_warmup=32,
    finetune_steps=64,
    n_envs=1,
    action_repeat=1,
    finetune_hyperparams=TINY_PPO,
    scratch_hyperparams=TINY_PPO,
)


def shrink_rollouts(patch, small: dict) -> None:
    """Through ``patch`` (a pytest MonkeyPatch), give every yaml entry that dpr.rl.train loads ``small`` on top (e.g.
    32-step PPO rollouts), so that a few dozen steps of RL are a few updates; the caller's overrides still win."""
    import dpr.rl.train as train_module

    original = train_module.load_hyperparams

    def shrunk(algo, env_id, preset="default", overrides=None):
        return original(algo, env_id, preset, {**small, **(overrides or {})})

    patch.setattr(train_module, "load_hyperparams", shrunk)


QUIET = {"show_progress": False, "log": lambda line: None}
# A tiny one-task pipeline run, and the same with three training seeds chosen from on two validation seeds.
PIPELINE = dict(TINY_PIPELINE, tasks=["navigation"], scratch_algos=["ppo"], test_seeds=[100])
THREE_SEEDS = {**PIPELINE, "train_seeds": [0, 1, 2], "validation_seeds": [200, 201]}


def run_tiny(settings: dict, out: Path, **kwargs):
    """Run (or resume) a tiny pipeline of ``settings`` into ``out`` in this process (``kwargs`` to run_pipeline);
    returns its report folder and log lines."""
    from dpr.pipeline.campaign import run_pipeline
    from dpr.pipeline.config import PipelineConfig

    lines: list[str] = []
    report = run_pipeline(PipelineConfig(**settings), out, show_progress=False, log=lines.append, **kwargs)
    return report, lines


def built_stages(lines: list[str]) -> list[str]:
    """The stages a pipeline log says were built (not taken from a store): their names, e.g. "navigation: bc,
    seed 0"."""
    return [line.split("] ", 1)[1].rsplit(": done in", 1)[0] for line in lines if ": done in " in line and "] " in line]


def parquet_files(root: Path, folder: str) -> list[str]:
    """The parquet files of a dataset ``folder`` ("data", "meta/episodes"), relative to the dataset ``root``."""
    return sorted(str(p.relative_to(root)) for p in (root / folder).glob("*/*.parquet"))


def assert_same_policy(path, other):
    """The two model files hold the same policy weights, tensor for tensor."""
    from dpr.policies.sb3 import load_model

    (first, _), (second, _) = load_model(path), load_model(other)
    weights = second.policy.state_dict()
    for name, tensor in first.policy.state_dict().items():
        assert (weights[name] == tensor).all(), name


class Stop(Exception):
    """Stands for a training process being killed."""


@contextlib.contextmanager
def stopped_after_snapshots(snapshots: int = 1):
    """Training runs inside snapshot at every rollout, and the first is stopped (:class:`Stop`, expected here)
    right after writing its ``snapshots``-th snapshot."""
    import pytest

    from dpr.rl import resume as resume_state

    written = []
    save = resume_state.save_snapshot

    def save_then_stop(*args, **kwargs):
        save(*args, **kwargs)
        written.append(1)
        if len(written) == snapshots:
            raise Stop

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(resume_state, "SNAPSHOT_SECONDS", 0.0)
        patch.setattr(resume_state, "save_snapshot", save_then_stop)
        with pytest.raises(Stop):
            yield


def change_a_reward(path: Path) -> None:
    """Rewrite the data file at ``path`` with one reward changed: parquet still decodes it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    rewards = table.column("next.reward").to_numpy().copy()
    rewards[3] = -4.3e24
    index = table.column_names.index("next.reward")
    pq.write_table(table.set_column(index, "next.reward", pa.array(rewards, table.schema.field(index).type)), path)


def small_batched_config(**overrides):
    """A `dpr train --engine batched` run of seconds: 4 updates of 8 steps x 4 envs of 4 disk robots, Navigation."""
    from dpr.rl.train import TrainConfig

    settings = dict(
        algo="ppo",
        env_id="dpr/Navigation-v0",
        n_robots=4,
        robot_model="disk",
        n_envs=4,
        timesteps=4 * 8 * 4,  # 4 updates of n_steps 8 x 4 envs
        preset="batched",
        engine="batched",
        steps_per_episode=12,
        hyperparams={"n_steps": 8, "batch_size": 16, "n_epochs": 2},
    )
    return TrainConfig(**{**settings, **overrides})


def _sigint_as_a_terminal_delivers_it() -> None:
    # A shell without job control starts background commands with SIGINT ignored, and children inherit that
    # (Python then installs no KeyboardInterrupt handler): give the command the disposition it has when typed.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_dpr_as_typed(argv: list[str], log: Path, env: dict | None = None) -> subprocess.Popen:
    """``dpr ARGV`` in a new session (its own process group, workers included), Ctrl-C not ignored, its output
    appended to ``log``."""
    with open(log, "ab") as handle:
        return subprocess.Popen(
            [sys.executable, "-m", "dpr.cli", *argv],
            cwd=Path(__file__).resolve().parents[1],
            stdout=handle,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env=env,
            preexec_fn=_sigint_as_a_terminal_delivers_it,
        )


@contextlib.contextmanager
def failed_if_left_running(process: subprocess.Popen, log: Path, message: str) -> Iterator[None]:
    """A ``process`` still running when the block ends (or fails) is killed with its process group, and the test
    fails with ``message`` and the process's log."""
    try:
        yield
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
            pytest.fail(f"{message}:\n{log.read_text()}")


def group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes in process group ``pgid``, from /proc."""
    members = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (comm) ": state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.append(int(entry.name))
    return members


def assert_group_ends(pgid: int, message: str, seconds: float = 10.0) -> None:
    """Every process of group ``pgid`` gone within ``seconds`` (a pool's resource tracker leaves once the main
    process's pipe closes)."""
    deadline = time.monotonic() + seconds
    while group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert group_members(pgid) == [], message

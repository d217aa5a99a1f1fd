#!/usr/bin/env python
"""Train LeRobot's Diffusion Policy or ACT on a dpr dataset with LeRobot's own training code, and score the trained
policy in the dpr env with dpr's metrics.

LeRobot is not a dependency of dpr (lerobot 0.4.x pins torch<2.11), so this runs in the LeRobot environment that
the top of ``tools/check_lerobot_load.py`` describes, with two more packages LeRobot's training code imports:

    /tmp/lerobot-venv/bin/pip install -c constraints.txt pyserial "diffusers>=0.27.2,<0.36"

From the repository root (``docs/lerobot-policies.md`` walks through a whole run):

    PYTHONPATH=$PWD /tmp/lerobot-venv/bin/python tools/lerobot_policies.py train --dataset DATASET --policy act \\
        --steps 1000 --out runs/act
    PYTHONPATH=$PWD /tmp/lerobot-venv/bin/python tools/lerobot_policies.py evaluate --model runs/act \\
        --seeds 320-339 --json runs/eval/act.json

``train`` builds LeRobot's ``TrainPipelineConfig`` (the dataset read through ``LeRobotDataset`` with the
``delta_timestamps`` the policy asks for, LeRobot's optimizer and scheduler presets) and runs LeRobot's
``lerobot_train.train``. The policy's settings are LeRobot's defaults except :data:`CPU_DEFAULTS` (a network a CPU
trains in minutes), and ``--set NAME=VALUE`` sets any field of the policy's config. The checkpoint lands in
``OUT/checkpoints/last/pretrained_model``; ``OUT/dpr_training.json`` records the run's wall and CPU seconds.

``evaluate`` rolls the trained policy out in the env the dataset was recorded on (its env id and env kwargs, from
the dataset's episode metadata), through :class:`LeRobotPolicyAdapter`: the env's state observation and
``environment_state()`` go in as ``observation.state`` and ``observation.environment_state``; the policy's action
(a chunk of continuous per-robot expansions, served one decision at a time by LeRobot's action queue) comes out as
the env's MultiBinary action, each robot expanding where the value is above one half. It writes the evaluation
file ``dpr evaluate --json`` writes, so ``dpr report`` tabulates it beside BC and the wave.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parent / "lerobot_plugin"))  # lerobot_env_dpr.decode_actions
import check_lerobot_load  # noqa: E402  (the LeRobot environment's set-up: offline hub, importable torchvision)

from dpr.datasets import features as F  # noqa: E402
from dpr.policies.registry import LEROBOT_ENV_FILE, LEROBOT_RUN_FOLDER  # noqa: E402

POLICIES = ("act", "diffusion")
# LeRobot's defaults are sized for GPUs and camera images; these train on two CPU cores in minutes. ACT's backbone
# (for pixel datasets) starts untrained: its ImageNet weights would need a download.
CPU_DEFAULTS: dict[str, dict[str, Any]] = {
    "act": {"dim_model": 128, "dim_feedforward": 512, "n_heads": 4, "chunk_size": 20, "n_action_steps": 10,
            "pretrained_backbone_weights": None},
    "diffusion": {"down_dims": (64, 128, 256), "horizon": 16, "n_action_steps": 8, "num_inference_steps": 10,
                  "noise_scheduler_type": "DDIM", "crop_shape": None},
}  # fmt: skip
TRAINING_RECORD = "dpr_training.json"
PHASE_SUFFIX = ".phase"  # action names of a dataset of phases (tools/lerobot_recipe.py phase-dataset)


def prepare() -> None:
    """LeRobot offline, its Arrow cache in a temporary folder, and torchvision importable beside the CPU torch."""
    check_lerobot_load.prepare_environment(Path(tempfile.mkdtemp(prefix="hf-cache-")))
    check_lerobot_load.make_torchvision_importable()


def policy_config(kind: str, **overrides: Any):
    """LeRobot's config of policy ``kind`` ("act" or "diffusion") on the CPU, with :data:`CPU_DEFAULTS` and
    ``overrides`` (any of its fields) over LeRobot's defaults."""
    if kind not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {kind!r}")
    if kind == "act":
        from lerobot.policies.act.configuration_act import ACTConfig as Config
    else:
        from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig as Config
    _check_fields(Config, overrides)
    settings = {**CPU_DEFAULTS[kind], **overrides, "device": "cpu", "push_to_hub": False}
    return Config(**settings)


def _check_fields(config_class: type, overrides: dict[str, Any]) -> None:
    """Every name in ``overrides`` must be a field of LeRobot's ``config_class`` (a ValueError naming --set)."""
    unknown = sorted(set(overrides) - set(config_class.__dataclass_fields__))
    if unknown:
        raise ValueError(f"--set: {unknown} are not fields of LeRobot's {config_class.__name__}")


def check_dataset(root: Path) -> None:
    """``root`` must be a dpr dataset carrying ``observation.environment_state`` (ACT and Diffusion Policy need it,
    or an image): a ValueError naming the folder and what to do otherwise."""
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ValueError(f"--dataset: {root} holds no meta/info.json; expected a dataset written by `dpr collect`")
    recorded = json.loads(info_path.read_text()).get("features", {})
    if F.ENVIRONMENT_STATE not in recorded and F.IMAGE not in recorded:
        raise ValueError(
            f"--dataset: {root} has no {F.ENVIRONMENT_STATE} (recorded by an older dpr) and no images; ACT and "
            "Diffusion Policy need one of them: record it again with `dpr collect`"
        )


def train(dataset: Path, kind: str, steps: int, batch_size: int, out: Path, seed: int = 0, **overrides: Any) -> Path:
    """Train policy ``kind`` on ``dataset`` for ``steps`` optimizer steps with LeRobot's training code into ``out``
    (which must not exist); returns the trained policy's folder."""
    from lerobot.configs.default import DatasetConfig, WandBConfig
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.scripts import lerobot_train

    check_dataset(dataset)
    if out.exists():
        raise ValueError(f"--out: {out} exists; LeRobot's training writes a new folder")
    config = TrainPipelineConfig(
        dataset=DatasetConfig(repo_id=f"dpr/{dataset.name}", root=str(dataset)),
        policy=policy_config(kind, **overrides),
        output_dir=out,
        seed=seed,
        steps=steps,
        batch_size=batch_size,
        num_workers=0,
        eval_freq=0,
        log_freq=max(1, steps // 20),
        save_freq=steps,
        wandb=WandBConfig(enable=False),
    )
    argv, sys.argv = sys.argv, sys.argv[:1]  # LeRobot's config validation reads the command line
    started, cpu_started = time.perf_counter(), time.process_time()
    try:
        lerobot_train.train(config)
    finally:
        sys.argv = argv
    record = {
        "policy": kind,
        "dataset": str(dataset),
        "steps": steps,
        "batch_size": batch_size,
        "seed": seed,
        "overrides": overrides,
        "wall_seconds": round(time.perf_counter() - started, 1),
        "cpu_seconds": round(time.process_time() - cpu_started, 1),
    }
    (out / TRAINING_RECORD).write_text(json.dumps(record, indent=2) + "\n")
    return out / LEROBOT_RUN_FOLDER


def training_step(dataset: Path, kind: str, batch_size: int = 4, **overrides: Any) -> tuple[float, dict]:
    """Build policy ``kind`` on ``dataset`` as LeRobot's training does (the dataset through ``LeRobotDataset``
    with the ``delta_timestamps`` the policy asks for, its normalising processor) and take one optimizer step on
    one batch; returns the batch's loss before the step and the frames the batch held per feature (its
    ``delta_timestamps``: 1 for a feature without)."""
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    check_dataset(dataset)
    config = policy_config(kind, **overrides)
    meta = LeRobotDatasetMetadata(f"dpr/{dataset.name}", root=dataset)
    delta_timestamps = resolve_delta_timestamps(config, meta)
    frames = LeRobotDataset(f"dpr/{dataset.name}", root=dataset, delta_timestamps=delta_timestamps)
    policy = make_policy(config, ds_meta=meta)
    preprocessor, _ = make_pre_post_processors(config, dataset_stats=meta.stats)
    batch = next(iter(torch.utils.data.DataLoader(frames, batch_size=batch_size, shuffle=True)))
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-4)
    loss, _ = policy.forward(preprocessor(batch))
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    held = {key: batch[key].shape[1] if key in (delta_timestamps or {}) else 1 for key in config.input_features}
    return float(loss.detach()), {**held, F.ACTION: batch[F.ACTION].shape[1]}


def policy_folder(model: Path) -> Path:
    """The policy's own folder: ``model`` itself, or its ``checkpoints/last/pretrained_model`` (a ``train`` output)."""
    return model / LEROBOT_RUN_FOLDER if (model / LEROBOT_RUN_FOLDER).is_dir() else model


def policy_env(model: Path, dataset: Path) -> tuple[str, dict]:
    """The env id and kwargs the policy in ``model`` was trained on: its ``dpr_env.json`` (a shipped policy, whose
    dataset is not at hand), else its dataset's episode rows."""
    from dpr.datasets.lerobot import LeRobotReader
    from dpr.imitation.bc import dataset_env

    env_file = policy_folder(model) / LEROBOT_ENV_FILE
    if env_file.is_file():
        recorded = json.loads(env_file.read_text())
        return recorded["env_id"], recorded["env_kwargs"]
    if not dataset.is_dir():
        raise ValueError(f"--model: {model} has no {LEROBOT_ENV_FILE} and its dataset {dataset} is not here")
    reader = LeRobotReader(dataset)
    env_id = reader.episodes[0][F.ENV_ID]
    return env_id, dataset_env(reader, env_id)[0]


def policy_actions(model: Path, dataset: Path) -> str:
    """What the policy's action values are, "expand" (0/1 per robot) or "phase": its ``dpr_env.json``'s
    ``actions``, else its dataset's action names (``robot0.phase``, ...: a phase dataset)."""
    env_file = policy_folder(model) / LEROBOT_ENV_FILE
    if env_file.is_file():
        return json.loads(env_file.read_text()).get("actions", "expand")
    names = json.loads((dataset / "meta" / "info.json").read_text())["features"][F.ACTION].get("names") or []
    return "phase" if names and all(name.endswith(PHASE_SUFFIX) for name in names) else "expand"


def load_policy(model: Path, **overrides: Any):
    """The trained policy in ``model`` (a ``train`` output folder or its ``pretrained_model``), with its
    processors and the dataset it was trained on. ``overrides``: fields of its config that act at inference only
    (e.g. ``n_action_steps``, ``num_inference_steps``, ACT's ``temporal_ensemble_coeff``)."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    folder = policy_folder(model)
    if not (folder / "config.json").is_file():
        raise ValueError(f"--model: {model} holds no trained LeRobot policy (no {LEROBOT_RUN_FOLDER}/config.json)")
    config = PreTrainedConfig.from_pretrained(folder)
    _check_fields(type(config), overrides)
    for name, value in overrides.items():
        setattr(config, name, value)
    config.__post_init__()  # LeRobot's own checks of the combination (e.g. n_action_steps against the horizon)
    config.device = "cpu"
    policy = get_policy_class(config.type).from_pretrained(folder, config=config)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        config, pretrained_path=str(folder), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    dataset = Path(json.loads((folder / "train_config.json").read_text())["dataset"]["root"])
    return policy, preprocessor, postprocessor, dataset


class LeRobotPolicyAdapter:
    """A LeRobot policy as a dpr ``policy(observation) -> action`` callable on a state-observation env: the state
    and the env's ``environment_state()`` go in (images, for a policy trained on pixels, from the env's render);
    the first action of the policy's queue comes out, thresholded into the env's MultiBinary action."""

    def __init__(self, policy, preprocessor, postprocessor, env, actions: str = "expand"):
        self.policy, self.preprocessor, self.postprocessor = policy, preprocessor, postprocessor
        self.actions = actions  # "expand" or "phase": lerobot_env_dpr.decode_actions
        self.env = env.unwrapped
        self.features = set(policy.config.input_features)

    def reset(self, seed: int | None = None) -> None:
        """Empty the policy's action and observation queues: a new episode starts. A seed also seeds torch, as
        lerobot_env_dpr's reset does, so a sampling policy draws the same noise on a seed in both evaluations."""
        import torch

        self.policy.reset()
        if seed is not None:
            torch.manual_seed(seed)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        import torch

        batch = {F.OBSERVATION: torch.as_tensor(observation, dtype=torch.float32)[None]}
        if F.ENVIRONMENT_STATE in self.features:
            batch[F.ENVIRONMENT_STATE] = torch.as_tensor(self.env.environment_state(), dtype=torch.float32)[None]
        if F.IMAGE in self.features:
            image = torch.as_tensor(self.env.render(), dtype=torch.float32) / 255.0  # as `dpr collect --pixels`
            batch[F.IMAGE] = image.permute(2, 0, 1)[None]
        with torch.inference_mode():
            action = self.postprocessor(self.policy.select_action(self.preprocessor(batch)))
        from lerobot_env_dpr import decode_actions

        return decode_actions(action[0].numpy(), self.actions)


def check_policy_fits(config, env) -> None:
    """The policy's features must be the env's (robots, state size, environment-state size): a ValueError naming
    each difference before any episode runs."""
    base = env.unwrapped
    have = {F.OBSERVATION: [int(np.prod(env.observation_space.shape))], F.ACTION: [base.n_robots]}
    have[F.ENVIRONMENT_STATE] = [len(base.environment_state_names)]
    features = {**config.input_features, **config.output_features}
    wrong = {
        key: (list(ft.shape), have[key]) for key, ft in features.items() if key in have and list(ft.shape) != have[key]
    }
    if wrong:
        details = "; ".join(f"{key}: policy {policy}, env {got}" for key, (policy, got) in wrong.items())
        raise ValueError(f"the policy does not fit the env ({base.spec.id if base.spec else base}): {details}")


def evaluate(
    model: Path,
    seeds: list[int],
    steps: int,
    json_path: Path,
    label: str | None = None,
    env_overrides: dict | None = None,
    **overrides: Any,
) -> list:
    """Score the policy in ``model`` (with inference-time config ``overrides``) on ``seeds`` over ``steps`` physics
    steps in the env its dataset was recorded on (with ``env_overrides`` over its kwargs; the policy must fit it),
    and write ``json_path`` as ``dpr evaluate --json`` does; returns the episodes' results."""
    import gymnasium as gym
    import torch

    import dpr  # noqa: F401  (registers the env ids)
    from dpr.envs import episode_steps
    from dpr.evaluation.scoring import episode_result, format_table, save_evaluation
    from dpr.rollout import roll_out

    if json_path.exists():
        raise ValueError(f"--json: {json_path} exists; choose a new file")
    torch.set_num_threads(1)
    policy, preprocessor, postprocessor, dataset = load_policy(model, **overrides)
    env_id, env_kwargs = policy_env(model, dataset)
    actions = policy_actions(model, dataset)
    env_kwargs = {**env_kwargs, **(env_overrides or {})}
    probe = gym.make(env_id, **env_kwargs)
    try:
        check_policy_fits(policy.config, probe)
    finally:
        probe.close()
    name = label or str(model)  # as `dpr evaluate` names a model: by its path, so that two runs stay apart
    render = {}
    if F.IMAGE in policy.config.input_features:  # trained on pixels: the env renders frames of the dataset's size
        render = {"render_mode": "rgb_array", "render_size": policy.config.input_features[F.IMAGE].shape[-1]}
    results = []
    for seed in seeds:
        env = gym.make(env_id, max_episode_steps=episode_steps(env_kwargs, steps), **env_kwargs, **render)
        try:
            adapter = LeRobotPolicyAdapter(policy, preprocessor, postprocessor, env, actions)
            outcome = roll_out(env, adapter, seed)
        finally:
            env.close()
        results.append(episode_result(env_id, name, seed, outcome, env_kwargs))
        print(f"{name} seed {seed}: {outcome.metrics.projected_displacement:.1f}", file=sys.stderr)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    save_evaluation(json_path, name, [env_id], env_kwargs, steps, seeds, results)
    print(format_table(results))
    return results


def _setting(text: str) -> tuple[str, Any]:
    """``NAME=VALUE``, VALUE read as `dpr --env-kwarg` reads it (JSON where it parses: numbers, lists, null)."""
    from dpr.cli.common import env_kwarg

    return env_kwarg(text, "--set")


def main(argv: list[str] | None = None) -> int:
    from dpr.cli.common import parse_seeds

    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    fit = commands.add_parser("train", help="train ACT or Diffusion Policy on a dpr dataset with LeRobot's code")
    fit.add_argument("--dataset", type=Path, required=True, help="a dataset folder written by `dpr collect`")
    fit.add_argument("--policy", choices=POLICIES, required=True)
    fit.add_argument("--steps", type=int, default=1000, help="optimizer steps (default 1000)")
    fit.add_argument("--batch-size", type=int, default=32, help="frames per batch (default 32)")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--out", type=Path, required=True, help="a new folder for LeRobot's outputs")
    fit.add_argument(
        "--set",
        type=_setting,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=f"a field of the policy's LeRobot config (over LeRobot's defaults and {CPU_DEFAULTS})",
    )
    score = commands.add_parser("evaluate", help="score a trained policy in the dpr env with dpr's metrics")
    score.add_argument("--model", type=Path, required=True, help="a `train` output folder")
    score.add_argument("--seeds", type=parse_seeds, default=list(range(320, 340)), help="e.g. 320-339 (default)")
    score.add_argument("--steps", type=int, default=2500, help="physics steps per episode (default 2500)")
    score.add_argument("--json", type=Path, required=True, help="the evaluation file to write (new)")
    score.add_argument("--label", help="the policy's name in the file (default: --model as given)")
    score.add_argument(
        "--set",
        type=_setting,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a config field that acts at inference, e.g. n_action_steps=1 (re-plan at every decision)",
    )
    score.add_argument(
        "--env-kwarg",
        type=_setting,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="over the dataset's env kwargs, e.g. n_robots=16 (the policy must fit the env)",
    )
    args = parser.parse_args(argv)
    prepare()
    if args.command == "train":
        folder = train(args.dataset, args.policy, args.steps, args.batch_size, args.out, args.seed, **dict(args.set))
        print(f"trained {args.policy}: {folder}")
    else:
        evaluate(args.model, args.seeds, args.steps, args.json, args.label, dict(args.env_kwarg), **dict(args.set))
    return 0


if __name__ == "__main__":
    sys.exit(main())

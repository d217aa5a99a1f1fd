"""`dpr evaluate` through dpr.cli.main: output files, and bad input refused before work; the commands' shape:
their flags, their defaults, and a light `dpr --help`."""

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import run_cli as run

import dpr
from dpr.cli import COMMANDS, PARAMETER_FLAGS, build_parser, flag_message
from dpr.cli.common import flag_for
from dpr.pipeline.config import PipelineConfig

SMALL = ["--robot-model", "disk", "--n-robots", "4", "--steps", "20", "--workers", "1"]


def test_evaluate_writes_episodes_and_summary(tmp_path, capsys):
    out = tmp_path / "eval.json"
    assert run(["evaluate", "--env", "dpr/Navigation-v0", "--seeds", "0-1", *SMALL, "--json", str(out)]) == 0
    payload = json.loads(out.read_text())
    assert [e["seed"] for e in payload["episodes"]] == [0, 1]
    for episode in payload["episodes"]:
        assert {"projected_displacement", "net_displacement", "total_distance", "success", "steps"} <= episode.keys()
        assert episode["steps"] == 20
    assert payload["summary"]["projected_displacement"]["n"] == 2
    assert "| dpr/Navigation-v0 | wave | projected_displacement |" in capsys.readouterr().out


def test_evaluate_passes_env_kwargs(tmp_path):
    out = tmp_path / "eval.json"
    argv = [
        "evaluate",
        "--env",
        "dpr/Manipulation-v0",
        "--seeds",
        "0",
        *SMALL,
        "--env-kwarg",
        "object_type=box",
        "--json",
        str(out),
    ]
    assert run(argv) == 0
    assert json.loads(out.read_text())["env_kwargs"]["object_type"] == "box"


def test_env_kwarg_values_read_as_json_or_as_python_constants():
    from dpr.cli.common import env_kwarg

    assert env_kwarg("obs_last_action=True") == ("obs_last_action", True)  # as gym.make(..., obs_last_action=True)
    assert env_kwarg("obs_last_action=false") == ("obs_last_action", False)
    assert env_kwarg("n_dead=None") == ("n_dead", None)
    assert env_kwarg("action_repeat=6") == ("action_repeat", 6)
    assert env_kwarg("object_type=box") == ("object_type", "box")
    assert env_kwarg("goal=[1, 2]") == ("goal", [1, 2])


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--env", "dpr/Nowhere-v0"], "--env: unknown env id"),
        (["--seeds", "4-1"], "--seeds must look like"),
        (["--policy", "expert"], "policy must be one of"),
        (["--env-kwarg", "object_start=nope", "--env", "dpr/Manipulation-v0"], "object_start must be one of"),
        (["--env-kwarg", "bogus=1"], "unexpected keyword argument 'bogus'"),
        (["--env-kwarg", "no-equals-sign"], "--env-kwarg must look like NAME=VALUE"),
    ],
)
def test_evaluate_refuses_bad_input(argv, message, capsys):
    assert run(["evaluate", *SMALL, "--seeds", "0", *argv]) == 2
    assert message in capsys.readouterr().err


def test_evaluate_never_overwrites_a_result(tmp_path, capsys):
    out = tmp_path / "eval.json"
    out.write_text("earlier results")
    assert run(["evaluate", "--seeds", "0", *SMALL, "--json", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_text() == "earlier results"


# -- the commands' shape -------------------------------------------------------------------------------------------
# The library parameters each command's handler can report (through dpr.checks.ParameterError, said as a flag by
# dpr.cli.common.flag_message): the parameters its library calls check, from the ParameterError(...) and
# check_*(...) calls of dpr.rl, dpr.imitation, dpr.datasets, dpr.viz and dpr.policies.sb3 they reach.
LIBRARY_PARAMETERS = {
    "evaluate": {"policy", "env_id", "env_ids"},
    "report": {"seed"},
    "compare": {"current", "candidate", "tasks"},
    "train": {
        *("n_robots", "robot_model", "n_envs", "steps_per_episode", "eval_episodes", "timesteps", "seed"),
        *("out", "env_id", "env_kwargs"),
    },
    "finetune": {
        *("init_from", "policy", "anchor_datasets", "anchor_weight", "anchor_decay", "critic_warmup"),
        *("timesteps", "seed", "n_envs", "eval_episodes", "out", "env_id", "env_kwargs"),
    },
    "finetune-decentralised": {
        *("init_from", "policy", "env_id", "algo", "n_robots", "timesteps", "critic_warmup", "seed"),
        *("eval_episodes", "env_kwargs", "hyperparams", "out", "shared_reward"),
    },
    "pipeline": {
        *("out", "preset", "config", "reuse", "backend", "workers", "address"),
        *(field.name for field in dataclasses.fields(PipelineConfig)),
    },  # each field is checked
    "bc": {
        *("dataset_dirs", "env_id", "algo", "epochs", "batch_size", "lr", "val_fraction", "patience", "seed", "out"),
        *("rounds", "episodes_per_round", "first_seed"),
    },
    "bc-decentralised": {
        *("dataset_dirs", "env_id", "algo", "epochs", "batch_size", "lr", "val_fraction", "patience", "seed", "out"),
        *("max_neighbours", "hold_steps", "n_phases"),
    },
    "collect": {
        *("env_id", "policy", "n_robots", "robot_model", "steps", "image_size", "env_kwargs"),
        *("episodes", "seed", "backend", "address"),
    },
    "replay": {"episodes"},
    "view": {"env_id", "env_kwargs", "episode", "policy", "path"},
    "bench": set(),
}
HEAVY_MODULES = ("torch", "stable_baselines3", "rerun", "pyarrow", "pandas", "matplotlib")


def _command_flags(command) -> set[str]:
    """A command's flags, and its positional arguments as its usage names them (``dpr compare CURRENT ...``)."""
    parser = argparse.ArgumentParser()
    command.arguments(parser)
    positionals = {action.metavar or action.dest for action in parser._actions if not action.option_strings}
    return set(parser._option_string_actions) | positionals


def test_every_command_lists_its_library_parameters():
    assert {command.name for command in COMMANDS} == set(LIBRARY_PARAMETERS)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda command: command.name)
def test_every_library_parameter_maps_to_a_flag_of_its_command(command):
    flags = _command_flags(command)
    unmapped = {name: flag_for(name, command.flags) for name in LIBRARY_PARAMETERS[command.name]}
    assert {name: flag for name, flag in unmapped.items() if flag not in flags} == {}


def test_every_mapped_parameter_is_a_library_parameter():
    """No stale entries: each name a flag map knows is a string the library (outside dpr.cli) spells."""
    package = Path(dpr.__file__).parent
    library = "\n".join(p.read_text() for p in package.rglob("*.py") if p.relative_to(package).parts[0] != "cli")
    mapped = set(PARAMETER_FLAGS).union(*(command.flags for command in COMMANDS))
    assert {name for name in mapped if f'"{name}"' not in library} == set()


def test_a_library_parameter_is_said_as_its_commands_flag():
    from dpr.checks import ParameterError

    view = next(command for command in COMMANDS if command.name == "view")
    assert flag_message(ParameterError("policy", "unknown")) == "--policy: unknown"
    assert flag_message(ParameterError("policy", "unknown"), view.flags) == "--policies: unknown"
    assert flag_message(ParameterError("env_kwargs", "bad")) == "--env-kwarg: bad"
    assert flag_message(ValueError("plain")) == "plain"


@pytest.mark.parametrize("argv", [["--help"], ["evaluate", "--help"], ["train", "--help"]])
def test_help_imports_nothing_heavy(argv):
    code = (
        "import sys\nfrom dpr.cli import main\n"
        f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
        "print(' '.join(sys.modules), file=sys.stderr)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "usage: dpr" in done.stdout
    loaded = {name.split(".")[0] for name in done.stderr.split()}
    assert loaded.isdisjoint(HEAVY_MODULES), sorted(loaded & set(HEAVY_MODULES))


def test_help_says_the_recipe_the_single_commands_default_to(capsys):
    """What `dpr bc`, `dpr finetune` and `dpr collect` do unless told: the pipeline's recipe, said in their help."""
    helps = {}
    for command in ("bc", "finetune", "finetune-decentralised", "collect"):
        assert run([command, "--help"]) == 0
        helps[command] = " ".join(capsys.readouterr().out.split())
    warmup = "default: a tenth of --timesteps, at most 10000"
    assert warmup in helps["finetune"] and warmup in helps["finetune-decentralised"]
    assert "gamma = 0.99^K and n_steps=512 batch_size=128 n_epochs=10" in helps["finetune"]
    assert "The actor of ppo and a2c is SwarmPolicy unless set here" in helps["bc"]
    assert "policy=MlpPolicy gives the yaml's MLP" in helps["bc"]
    assert "records with --env-kwarg obs_last_action=true by default" in helps["collect"]
    finetune = build_parser().parse_args(["finetune", "--from", "m.zip", "--env", "dpr/Navigation-v0"])
    assert finetune.critic_warmup is None  # resolved from the run's timesteps (dpr.rl.recipe.default_critic_warmup)


def test_defaults_come_from_the_library():
    from dpr.cli.learn import BATCHED_ENVS, resolve_engine_defaults
    from dpr.envs import MAX_EPISODE_STEPS
    from dpr.rl.train import TrainConfig

    args = build_parser().parse_args(["train", "--algo", "ppo", "--env", "dpr/Navigation-v0"])
    resolve_engine_defaults(args)
    assert args.steps_per_episode is None is TrainConfig.steps_per_episode  # a whole episode of the env kwargs
    assert TrainConfig("ppo", "dpr/Navigation-v0").steps_per_episode == MAX_EPISODE_STEPS
    assert (args.n_robots, args.robot_model, args.n_envs) == (
        TrainConfig.n_robots,
        TrainConfig.robot_model,
        TrainConfig.n_envs,
    )
    batched = build_parser().parse_args(["train", "--algo", "ppo", "--env", "dpr/Navigation-v0", "--engine", "batched"])
    resolve_engine_defaults(batched)
    assert (batched.n_envs, batched.preset) == (BATCHED_ENVS, "batched")


@pytest.mark.parametrize("flag", ["--out", "--json"])
def test_an_unwritable_destination_is_refused_before_any_work(flag, tmp_path, capsys):
    """A path under a file (where nothing can be written) is refused at once, not after the work."""
    from dpr.cli import main

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    paths = {"--out": tmp_path / "dataset", "--json": tmp_path / "summary.json"}
    paths[flag] = blocker / "x"
    argv = ["collect", "--env", "dpr/Navigation-v0", "--episodes", "1", "--steps", "5"]
    argv += ["--out", str(paths["--out"]), "--json", str(paths["--json"])]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert f"{flag}: {blocker} is not a folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]

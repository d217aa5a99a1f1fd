"""`dpr evaluate` and `dpr bench` through dpr.cli.main: output files, and bad input refused before work."""

import json

import pytest
from helpers import run_cli as run

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

"""tools/model_agreement.py: the paddle-against-disk table, its checks and its resumable cache."""

import json
import sys

import pytest
from helpers import load_tool


@pytest.fixture(scope="module")
def agreement():
    return load_tool("model_agreement")


def test_runs_both_models_caches_every_episode_and_resumes(agreement, tmp_path, monkeypatch, capsys):
    cache, table = tmp_path / "episodes.jsonl", tmp_path / "table.json"
    argv = ["--sizes", "4", "--seeds", "0", "--steps", "30", "--workers", "1", "--cache", str(cache)]
    monkeypatch.setattr(sys, "argv", ["model_agreement.py", *argv, "--json", str(table)])
    code = agreement.main()
    rows = json.loads(table.read_text())
    assert len(rows) == 1 and rows[0]["n_robots"] == 4
    row = rows[0]
    for model in ("paddle", "disk"):
        assert row[f"{model}_default_side"] == "near"
        assert row[f"{model}_default"] == row[f"{model}_near"]
    assert row["same_sign"] == ((row["paddle_default"] > 0) == (row["disk_default"] > 0))
    assert row["agrees"] == (row["same_sign"] and 0.5 <= row["ratio"] <= 2.0)
    assert code == (0 if row["agrees"] else 1)
    lines = [json.loads(line) for line in cache.read_text().splitlines()]
    assert sorted(entry["key"] for entry in lines) == sorted(
        f"{model}/4/{side}/{hold}/30/0" for model, hold in (("paddle", 10), ("disk", 4)) for side in ("near", "far")
    )
    out = capsys.readouterr()
    assert "| 4 |" in out.out and "0 cached, 4 to run" in out.err

    # a second run takes every episode from the cache and prints the same table
    monkeypatch.setattr(sys, "argv", ["model_agreement.py", *argv])
    assert agreement.main() == code
    again = capsys.readouterr()
    assert "4 cached, 0 to run" in again.err and again.out == out.out


def test_refuses_a_swarm_too_small_for_a_wave(agreement, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["model_agreement.py", "--sizes", "1"])
    with pytest.raises(SystemExit) as exit_info:
        agreement.main()
    assert exit_info.value.code == 2 and "--sizes" in capsys.readouterr().err

"""tools/bench_gpu.sh: which parts it runs, and what it refuses before any work (its figures need a GPU)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "tools" / "bench_gpu.sh"


def run_script(out: Path, python: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", str(SCRIPT), str(out)],
        env={**os.environ, "PYTHON": python, **env},
        capture_output=True,
        text=True,
        timeout=120,
    )


def recording_python(tmp_path: Path) -> tuple[str, Path]:
    """A stand-in for python that logs each command line it is given and succeeds."""
    calls = tmp_path / "calls.txt"
    fake = tmp_path / "python"
    fake.write_text(f'#!/usr/bin/env bash\necho "$*" >> {calls}\n')
    fake.chmod(0o755)
    return str(fake), calls


def test_parts_runs_only_the_parts_it_names(tmp_path):
    python, calls = recording_python(tmp_path)
    result = run_script(tmp_path / "out", python, PARTS="bench-training bench-batched-compiled")
    assert result.returncode == 0, result.stderr
    commands = calls.read_text().splitlines()
    benches = [line for line in commands if "bench" in line]
    assert len(benches) == 2
    assert "tools/bench_training.py" in benches[0]
    assert "--compile" in benches[1] and "bench-batched-compiled.json" in benches[1]
    assert "== bench-batched (" not in result.stdout


def test_every_part_runs_by_default(tmp_path):
    python, calls = recording_python(tmp_path)
    result = run_script(tmp_path / "out", python)
    assert result.returncode == 0, result.stderr
    commands = calls.read_text().splitlines()
    assert sum("bench" in line for line in commands) == 4
    assert [line for line in commands if "profile_batched.py" in line] == [
        f"tools/profile_batched.py --device cuda --compile --out {tmp_path / 'out' / 'profile-batched'}"
    ]


def test_unknown_part_is_refused_before_any_work(tmp_path):
    python, calls = recording_python(tmp_path)
    result = run_script(tmp_path / "out", python, PARTS="bench-batched bench-gpu")
    assert result.returncode == 2
    assert "PARTS: no part named 'bench-gpu'" in result.stderr
    assert not calls.exists() and not (tmp_path / "out").exists()


def test_a_machine_without_cuda_is_refused_before_any_part(tmp_path):
    result = run_script(tmp_path / "out", sys.executable, CUDA_VISIBLE_DEVICES="")
    assert result.returncode == 1
    assert "no CUDA device" in result.stderr
    assert not list((tmp_path / "out").iterdir())


def test_the_profile_tool_writes_its_tables_and_summary_on_the_cpu(tmp_path):
    """tools/profile_batched.py at a tiny size: what the profile-batched part brings back from a GPU (here without
    the device's columns), and a folder that exists is refused before any work."""
    tool = SCRIPT.parent / "profile_batched.py"
    out = tmp_path / "profile"
    tiny = ["--num-envs", "4", "--ppo-envs", "4", "--steps", "1", "--n-robots", "4", "--n-steps", "2", "--rows", "5"]
    tiny += ["--out", str(out)]
    result = subprocess.run([sys.executable, str(tool), *tiny], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "profile.json").read_text())
    assert summary["env_step"]["wall_seconds"] > 0 and summary["ppo_round"]["samples"] == 4 * 2
    assert summary["env_step"]["kernel_launches"] == 0 and summary["ppo_round"]["device_busy_share"] is None
    assert "aten::" in (out / "env_step.txt").read_text() and "aten::" in (out / "ppo_round.txt").read_text()
    again = subprocess.run([sys.executable, str(tool), *tiny], capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and f"--out: {out} exists" in again.stderr

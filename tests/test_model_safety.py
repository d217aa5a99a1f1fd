"""Model files cannot run code: loading one unpickles nothing, and a file holding a pickled entry that no dpr model
holds is refused by every command that takes a model, before any work."""

from __future__ import annotations

import base64
import json
import zipfile
from pathlib import Path

import cloudpickle
import pytest
import yaml
from helpers import run_cli as run

from dpr.checks import ParameterError
from dpr.policies.sb3 import load_model

MODELS = Path(__file__).resolve().parents[1] / "models"


class CreatesAFile:
    """Unpickled, it creates the file ``marker``: what a crafted model file would do."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def crafted(tmp_path: Path, key: str, source: str = "navigation-bc.zip") -> tuple[Path, Path]:
    """A copy of a shipped model whose ``data`` member holds, under ``key``, a pickle that creates a file."""
    marker = tmp_path / f"created-by-{key}"
    path = tmp_path / "crafted.zip"
    with zipfile.ZipFile(MODELS / source) as original, zipfile.ZipFile(path, "w") as copy:
        for item in original.infolist():
            content = original.read(item)
            if item.filename == "data":
                data = json.loads(content)
                payload = base64.b64encode(cloudpickle.dumps(CreatesAFile(marker))).decode()
                entry = data.get(key) if isinstance(data.get(key), dict) else {":type:": "<class 'object'>"}
                data[key] = {**entry, ":serialized:": payload}  # an entry SB3 writes keeps its plain fields
                content = json.dumps(data).encode()
            copy.writestr(item, content)
    return path, marker


def test_a_pickled_entry_no_dpr_model_holds_is_refused_unread(tmp_path):
    path, marker = crafted(tmp_path, "surprise")
    with pytest.raises(ParameterError, match=r"pickled entries no dpr model holds \(surprise\)"):
        load_model(path)
    assert not marker.exists()


@pytest.mark.parametrize("key", ["observation_space", "policy_class", "clip_range", "_last_obs"])
def test_the_pickled_entries_sb3_writes_are_never_unpickled(tmp_path, key):
    """Where a model file holds a pickle, dpr supplies the object itself; the pickle is never read."""
    path, marker = crafted(tmp_path, key, "navigation-bc-ppo.zip")
    model, _ = load_model(path)
    assert not marker.exists()
    assert model.observation_space.shape == (64,)


def test_a_policy_class_dpr_does_not_train_is_refused(tmp_path):
    path = tmp_path / "other.zip"
    with zipfile.ZipFile(MODELS / "navigation-bc.zip") as original, zipfile.ZipFile(path, "w") as copy:
        for item in original.infolist():
            content = original.read(item)
            if item.filename == "data":
                data = json.loads(content)
                data["policy_class"]["__module__"] = "somebody.elses.policies"
                content = json.dumps(data).encode()
            copy.writestr(item, content)
    with pytest.raises(ParameterError, match="none of the policies dpr trains"):
        load_model(path)


def test_loading_without_unpickling_keeps_the_policy(tmp_path):
    """The model loaded from its plain entries acts as the one SB3 unpickles (the reference below, from the
    repository's own file) does."""
    import numpy as np
    from stable_baselines3 import PPO

    path = MODELS / "navigation-bc-ppo.zip"
    ours, _ = load_model(path)
    theirs = PPO.load(path, device="cpu", custom_objects={"clip_range": 0.0, "lr_schedule": lambda _: 0.0})
    observations = np.random.default_rng(0).normal(size=(32, 64)).astype(np.float32)
    np.testing.assert_array_equal(
        ours.predict(observations, deterministic=True)[0], theirs.predict(observations, deterministic=True)[0]
    )
    assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space


def test_every_command_that_takes_a_model_refuses_the_crafted_file(tmp_path, capsys):
    path, marker = crafted(tmp_path, "surprise")
    card = tmp_path / "card.yaml"
    entry = {"task": "navigation", "method": "bc", "file": path.name, "made_by": "a test"}
    card.write_text(yaml.safe_dump({"format": 1, "models": [entry]}))
    commands = [
        ["evaluate", "--policy", str(path), "--env", "dpr/Navigation-v0", "--seeds", "0", "--steps", "10"],
        [
            "finetune",
            "--from",
            str(path),
            "--env",
            "dpr/Navigation-v0",
            "--out",
            str(tmp_path / "runs"),
            "--timesteps",
            "64",
        ],
        [
            "collect",
            "--policy",
            str(path),
            "--env",
            "dpr/Navigation-v0",
            "--episodes",
            "1",
            "--out",
            str(tmp_path / "ds"),
        ],
        ["pipeline", "--out", str(tmp_path / "pipeline"), "--shipped", str(card)],
        [
            "view",
            "--env",
            "dpr/Navigation-v0",
            "--policies",
            str(path),
            "--steps",
            "10",
            "--save",
            str(tmp_path / "v.rrd"),
        ],
    ]
    for argv in commands:
        assert run(argv) == 2, argv
        assert "pickled entries no dpr model holds" in capsys.readouterr().err, argv
    assert not marker.exists()
    assert not any((tmp_path / name).exists() for name in ("runs", "ds", "pipeline", "v.rrd"))


def test_pickled_policy_kwargs_are_read_from_their_plain_fields(tmp_path):
    """SB3 pickles policy_kwargs that name classes (A2C's RMSprop); dpr reads the fields and maps the classes it
    knows, never the pickle, and refuses a class it does not know."""
    path, marker = crafted(tmp_path, "policy_kwargs")
    data = json.loads(zipfile.ZipFile(path).read("data"))
    assert load_model(path)[0].policy.optimizer_class.__name__ == "Adam"  # the plain fields: nothing named
    data["policy_kwargs"]["optimizer_class"] = "<class 'torch.optim.rmsprop.RMSprop'>"
    _rewrite_data(path, data)
    assert load_model(path)[0].policy.optimizer_class.__name__ == "RMSprop"
    data["policy_kwargs"]["activation_fn"] = "<class 'builtins.eval'>"
    _rewrite_data(path, data)
    with pytest.raises(ParameterError, match="policy_kwargs activation_fn is <class 'builtins.eval'>"):
        load_model(path)
    assert not marker.exists()


def _rewrite_data(path: Path, data: dict) -> None:
    members = {}
    with zipfile.ZipFile(path) as archive:
        for item in archive.infolist():
            members[item.filename] = archive.read(item)
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def crafted_weights(tmp_path: Path, member: str = "policy.pth") -> tuple[Path, Path]:
    """A copy of a shipped model whose weights member ``member`` is a torch file holding a pickle that creates a
    file."""
    import io

    import torch

    marker = tmp_path / "created-by-weights"
    buffer = io.BytesIO()
    torch.save({"weights": CreatesAFile(marker)}, buffer)
    path = tmp_path / "crafted-weights.zip"
    with zipfile.ZipFile(MODELS / "navigation-bc.zip") as original, zipfile.ZipFile(path, "w") as copy:
        for item in original.infolist():
            copy.writestr(item, buffer.getvalue() if item.filename == member else original.read(item))
    return path, marker


def test_a_weights_file_holding_a_pickle_is_one_clean_error_without_torchs_advice(tmp_path, capsys):
    """torch refuses the pickle (weights_only=True) and says loading with weights_only=False "will likely
    succeed": dpr names the file, exits 2, and never passes that advice on."""
    path, marker = crafted_weights(tmp_path)
    with pytest.raises(ParameterError, match="its weights hold a pickle that calls") as caught:
        load_model(path)
    assert str(path) in str(caught.value) and "weights_only" not in str(caught.value)
    argv = ["evaluate", "--policy", str(path), "--env", "dpr/Navigation-v0", "--seeds", "0", "--steps", "10"]
    assert run(argv) == 2
    err = capsys.readouterr().err
    assert f"--policy: {path}: its weights hold a pickle" in err
    assert "weights_only" not in err and "Traceback" not in err and "trust" not in err
    assert not marker.exists()


def test_a_snapshot_weights_file_holding_a_pickle_is_refused_without_torchs_advice(tmp_path):
    import torch

    from dpr.rl.resume import _read_weights

    marker = tmp_path / "created"
    torch.save({"policy": CreatesAFile(marker), "optimizer": {}}, tmp_path / "weights.pt")
    with pytest.raises(ValueError, match="not the weights of a snapshot .it holds a pickle that calls") as caught:
        _read_weights(tmp_path / "weights.pt")
    assert "weights_only" not in str(caught.value) and not marker.exists()

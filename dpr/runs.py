"""Run folders of the commands that write models and logs (`dpr bc`, `dpr train`, `dpr finetune`,
`dpr pipeline`): always new ones, so nothing already written is overwritten; and what a run records about the
software it ran on."""

from __future__ import annotations

import importlib.metadata
import platform
import time
from pathlib import Path

from dpr.checks import ParameterError
from dpr.envs import TASKS

# The packages whose versions a run's config.yaml records.
VERSIONED = ("deep-particle-robot", "stable-baselines3", "torch", "gymnasium", "numpy", "pymunk")


def fresh_path(path: str | Path) -> Path:
    """``path``, or ``path-2``, ``path-3``... the first that does not exist yet (two runs started in the same
    second, or an interrupted attempt left the first behind)."""
    base = candidate = Path(path)
    n = 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate


def attempt_paths(path: str | Path) -> list[Path]:
    """``path`` and the folders :func:`fresh_path` started beside it (``path-2``, ``path-3``...), oldest first."""
    base = Path(path)
    beside = [p for p in base.parent.glob(f"{base.name}-*") if p.name.rsplit("-", 1)[1].isdigit()]
    return [base, *sorted(beside, key=lambda p: int(p.name.rsplit("-", 1)[1]))]


def check_new_folder(out: str | Path | None) -> None:
    """A :class:`ParameterError` about ``out`` when it exists and is not an empty folder (``None``: a default
    folder will be made)."""
    if out is not None:
        path = Path(out)
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise ParameterError("out", f"{path} already exists and is not an empty folder; runs are never overwritten")


def default_run_dir(runs_dir: str | Path, env_id: str, name: str, seed: int) -> Path:
    """``runs_dir/<task>-<name>-seed<S>-<timestamp>``, made unique with :func:`fresh_path`."""
    return fresh_path(Path(runs_dir) / f"{TASKS[env_id]}-{name}-seed{seed}-{time.strftime('%Y%m%d-%H%M%S')}")


def package_versions() -> dict[str, str]:
    """The Python version and those of :data:`VERSIONED` ("not installed" for a missing one)."""
    versions = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions

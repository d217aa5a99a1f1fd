"""Saving and loading SB3 models together with the env they were trained on.

A model file is SB3's zip plus a ``dpr_env.json`` member (see :mod:`dpr.policies.sb3`, which owns the format
so that ``dpr evaluate --policy MODEL.zip`` works without importing this package).
"""

from __future__ import annotations

from pathlib import Path

from dpr.policies.sb3 import METADATA_MEMBER, ModelInfo, load_model, read_model_info, write_model_info

__all__ = ["METADATA_MEMBER", "ModelInfo", "load_model", "read_model_info", "save_model"]


def save_model(model, path: str | Path, info: ModelInfo) -> Path:
    """Save ``model`` to ``path`` (a ``.zip`` file, replaced if present) with ``info`` inside it."""
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"model path must end in .zip, got {path}")
    model.save(path)  # a fresh zip: any metadata of an older file at this path is gone with it
    write_model_info(path, info)
    return path

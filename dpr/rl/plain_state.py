"""State written as files that run no code when read: a tree of JSON values, with its numpy arrays and torch tensors
in a numpy ``.npz`` beside it (read with ``allow_pickle=False``).

:func:`write_state` takes a tree of ``None``, bools, ints, floats (``inf`` and ``nan`` too), strings, lists, tuples,
dicts, numpy scalars and arrays (not of objects) and CPU torch tensors; :func:`read_state` gives the same tree
back, each value of the same type, dtype and shape (a list of arrays alike in dtype and shape is stored as one
stacked array). Anything else is a TypeError when written: nothing that only a pickle could hold is kept.
"""

from __future__ import annotations

import json
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

_MARK = "$"  # the keys of the JSON objects that stand for values JSON has no type for begin with it


def _is_tensor(value) -> bool:
    torch = sys.modules.get("torch")  # (a tree holds tensors only where torch is imported already)
    return torch is not None and isinstance(value, torch.Tensor)


def _array(value: np.ndarray, arrays: dict[str, np.ndarray], kind: str) -> dict[str, str]:
    if value.dtype.hasobject:
        raise TypeError(f"an array of {value.dtype} cannot be stored without pickling it")
    name = f"a{len(arrays)}"
    arrays[name] = value
    return {kind: name}


def _encode(value, arrays: dict[str, np.ndarray]):
    if value is None or isinstance(value, (bool, str)) or type(value) in (int, float):
        return value
    if isinstance(value, np.generic):
        return {_MARK + "scalar": [value.dtype.str, value.item()]}
    if isinstance(value, np.ndarray):
        return _array(value, arrays, _MARK + "array")
    if _is_tensor(value):
        return _array(value.detach().cpu().numpy(), arrays, _MARK + "tensor")
    if isinstance(value, tuple):
        return {_MARK + "tuple": [_encode(item, arrays) for item in value]}
    if isinstance(value, list):
        first = value[0] if value else None
        if isinstance(first, np.ndarray) and all(
            isinstance(item, np.ndarray) and item.dtype == first.dtype and item.shape == first.shape for item in value
        ):
            return _array(np.stack(value), arrays, _MARK + "arrays")
        return [_encode(item, arrays) for item in value]
    if isinstance(value, dict):
        if all(isinstance(key, str) and not key.startswith(_MARK) for key in value):
            return {key: _encode(item, arrays) for key, item in value.items()}
        return {_MARK + "items": [[_encode(key, arrays), _encode(item, arrays)] for key, item in value.items()]}
    raise TypeError(f"a {type(value).__name__} cannot be stored without pickling it")


def _decode(value, arrays):
    if isinstance(value, list):
        return [_decode(item, arrays) for item in value]
    if not isinstance(value, dict):
        return value
    if len(value) == 1:
        ((key, inner),) = value.items()
        if key == _MARK + "scalar":
            return np.dtype(inner[0]).type(inner[1])
        if key == _MARK + "array":
            return arrays[inner]
        if key == _MARK + "arrays":
            stacked = arrays[inner]
            return [stacked[index, ...] for index in range(len(stacked))]  # (0-d arrays stay arrays)
        if key == _MARK + "tensor":
            import torch

            return torch.from_numpy(arrays[inner].copy())
        if key == _MARK + "tuple":
            return tuple(_decode(item, arrays) for item in inner)
        if key == _MARK + "items":
            return {_decode(k, arrays): _decode(item, arrays) for k, item in inner}
    return {key: _decode(item, arrays) for key, item in value.items()}


def write_state(tree: Any, json_path: Path, npz_path: Path) -> None:
    """Write ``tree`` as ``json_path`` and its arrays as ``npz_path`` (a TypeError, writing nothing, for a value
    that only a pickle could hold)."""
    arrays: dict[str, np.ndarray] = {}
    text = json.dumps(_encode(tree, arrays))
    with open(npz_path, "wb") as file:
        np.savez(file, **arrays)
    Path(json_path).write_text(text)


def read_state(json_path: Path, npz_path: Path) -> Any:
    """The tree :func:`write_state` wrote (a ValueError when a file is not of that form; nothing is unpickled)."""
    try:
        tree = json.loads(Path(json_path).read_text())
        with np.load(npz_path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
        return _decode(tree, arrays)
    except (OSError, ValueError, zipfile.BadZipFile, KeyError, IndexError, TypeError) as error:
        raise ValueError(f"{json_path.parent}: not a snapshot dpr can read ({error})") from None

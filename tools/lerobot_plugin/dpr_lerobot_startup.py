"""Imported at start-up by the LeRobot side environment (a ``.pth`` file that ``tools/lerobot_env.sh`` writes), so
that LeRobot's own commands (``lerobot-train``, ``lerobot-eval``) run there as they are.

The torchvision wheel for torch 2.13 is a CUDA build whose compiled ops do not load beside the CPU torch, and its
import then fails declaring fake kernels for ``nms``/``qnms``. This hook waits for the first ``import torchvision``
and declares those two ops just before it (``tools/check_lerobot_load.py``'s ``make_torchvision_importable``);
LeRobot's state-only policies use no torchvision op. It imports nothing heavy until torchvision is asked for.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import os
import sys
from pathlib import Path

_LIBRARY = None  # kept alive: dropping a torch.library.Library removes its schemas


def declare_torchvision_ops() -> None:
    """Load torchvision's compiled ops, or, where they do not load beside this torch, declare ``nms`` and
    ``qnms`` so that torchvision's import can register its fake kernels (also what
    ``tools/check_lerobot_load.py``'s ``make_torchvision_importable`` calls)."""
    global _LIBRARY
    import torch

    spec = importlib.util.find_spec("torchvision")
    extension = next(iter(sorted(Path(spec.origin).parent.glob("_C*.so"))), None) if spec and spec.origin else None
    try:
        if extension is not None:
            torch.ops.load_library(str(extension))
            return
    except OSError:
        pass
    try:
        _LIBRARY = torch.library.Library("torchvision", "DEF")
    except RuntimeError:  # declared already
        return
    for name in ("nms", "qnms"):
        _LIBRARY.define(f"{name}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")


class _TorchvisionHook(importlib.abc.MetaPathFinder):
    """Runs :func:`declare_torchvision_ops` once, when torchvision is first imported; finds nothing itself."""

    def find_spec(self, name, path=None, target=None):
        if name == "torchvision":
            sys.meta_path.remove(self)
            declare_torchvision_ops()
        return None


def install() -> None:
    """The hook, and LeRobot kept off the network (a missing file fails at once instead of downloading)."""
    for key, value in {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "SDL_VIDEODRIVER": "dummy"}.items():
        os.environ.setdefault(key, value)
    if "torchvision" not in sys.modules and not any(isinstance(f, _TorchvisionHook) for f in sys.meta_path):
        sys.meta_path.insert(0, _TorchvisionHook())

"""Why a torch file that dpr reads with ``weights_only=True`` was refused, said without torch's own advice.

torch's refusal of a pickle that is not plain weights (an ``UnpicklingError``) tells the reader that loading the
file with ``weights_only=False`` "will likely succeed": that would run whatever the file's pickle calls. dpr never
passes that on. :func:`refused_pickle` keeps only what the file holds (the global torch would not load)."""

from __future__ import annotations

import pickle
import re

_GLOBAL = re.compile(r"Unsupported global: GLOBAL ([\w.<>]+)")
_OPERAND = re.compile(r"Unsupported operand (\d+)")


def is_refused_pickle(error: BaseException) -> bool:
    """Whether ``error`` is torch refusing a file whose pickle is more than weights (or no pickle at all)."""
    return isinstance(error, pickle.UnpicklingError) or "Weights only load failed" in str(error)


def refused_pickle(error: BaseException) -> str:
    """What was wrong with the file, in a few words, e.g. "a pickle that calls builtins.getattr, which plain
    weights never do": never torch's message itself, which advises loading the file with ``weights_only=False``."""
    text = str(error)
    found = _GLOBAL.search(text)
    if found:
        return f"a pickle that calls {found.group(1)}, which plain weights never do"
    found = _OPERAND.search(text)
    if found:
        return f"a pickle with operation {found.group(1)}, which plain weights never use"
    return "a pickle that is not plain weights"

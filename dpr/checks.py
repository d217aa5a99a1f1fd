"""Argument checks shared by the library, and the error that names the parameter it is about.

Library functions check their arguments before any work starts and raise :class:`ParameterError`, whose message
starts with the *library's* parameter name (``"dataset_dirs: ..."``). The CLI catches it and says the same with
its own flag (``"--dataset: ..."``), so that each layer speaks its own vocabulary.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from typing import Any

import numpy as np


class ParameterError(ValueError):
    """A bad value for the parameter ``parameter``; ``problem`` says what is wrong and what was expected."""

    def __init__(self, parameter: str, problem: str):
        self.parameter = parameter
        self.problem = problem
        super().__init__(f"{parameter}: {problem}")

    def __reduce__(self):  # rebuilt from both fields when it crosses a process boundary (worker pools)
        return type(self), (self.parameter, self.problem)


def check_int(name: str, value: Any, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as a Python int (a numpy integer is accepted, a bool is not) within [minimum, maximum]."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ParameterError(name, f"expected an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ParameterError(name, f"must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ParameterError(name, f"must be <= {maximum}, got {value}")
    return value


def check_number(
    name: str,
    value: Any,
    minimum: float | None = None,
    maximum: float | None = None,
    *,
    above: float | None = None,
    below: float | None = None,
) -> float:
    """``value`` as a finite float within [minimum, maximum] (``above``/``below``: strict bounds)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(name, f"expected a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(name, f"must be finite, got {value}")
    if minimum is not None and value < minimum:
        raise ParameterError(name, f"must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ParameterError(name, f"must be <= {maximum}, got {value}")
    if above is not None and not value > above:
        raise ParameterError(name, f"must be > {above}, got {value}")
    if below is not None and not value < below:
        raise ParameterError(name, f"must be < {below}, got {value}")
    return value


def check_number_range(
    name: str, value: Any, minimum: float | None = None, maximum: float | None = None
) -> tuple[float, float]:
    """``value``, a number or ``[low, high]``, as the checked (low, high) it is drawn from (a number: both)."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise ParameterError(name, f"expected a number or [low, high], got {value!r}")
        low, high = (check_number(name, item, minimum, maximum) for item in value)
        if low > high:
            raise ParameterError(name, f"expected [low, high] with low <= high, got {value!r}")
        return low, high
    low = check_number(name, value, minimum, maximum)
    return low, low


def check_seeds(
    name: str,
    seeds: Iterable[Any],
    *,
    allow_empty: bool = False,
    maximum: int | None = None,
    max_count: int | None = None,
) -> list[int]:
    """``seeds`` as ints in [0, maximum], each once (a repeated seed would count its episode twice in every
    statistic), at most ``max_count`` of them, and at least one unless ``allow_empty``."""
    seeds = list(seeds)
    if max_count is not None and len(seeds) > max_count:
        raise ParameterError(name, f"must name at most {max_count} seeds, got {len(seeds)}")
    seeds = [check_int(name, seed, 0, maximum) for seed in seeds]
    if not seeds and not allow_empty:
        raise ParameterError(name, "must name at least one seed")
    repeated = sorted(seed for seed, count in Counter(seeds).items() if count > 1)
    if repeated:
        raise ParameterError(name, f"each seed must appear once; repeated: {repeated[:10]}")
    return seeds


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ParameterError(name, f"expected one of {list(choices)}, got {value!r}")
    return value

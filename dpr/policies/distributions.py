"""torch.distributions' argument checks, off while a learner runs.

Every action distribution torch builds checks its parameters (and every ``log_prob`` its sample) against their
constraints, and each check reads a flag back from the tensors: a host synchronisation on a GPU, and a few percent of
a batched PPO update on a CPU. The learners run inside :func:`unchecked_distributions`; an action
sampled from bad parameters still fails in torch's sampler (``bernoulli`` and ``multinomial`` refuse probabilities
that are not numbers in [0, 1]), and a loss gone bad shows in the next rollout's sampling.

torch is imported inside the function, as in :mod:`dpr.policies.sb3`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["unchecked_distributions"]


@contextmanager
def unchecked_distributions() -> Iterator[None]:
    """Within: distributions built without ``validate_args`` skip their checks (the values they give are the same);
    the setting before is back after."""
    from torch.distributions import Distribution

    before = Distribution._validate_args
    Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        Distribution.set_default_validate_args(before)

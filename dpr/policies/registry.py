"""Policies by name: what ``dpr evaluate`` and ``dpr collect`` accept as ``--policy``.

Every policy made here is a callable ``policy(observation) -> action`` with ``reset(seed)``, called once
per episode right after ``env.reset(seed=seed)``.
"""

from __future__ import annotations

SCRIPTED_POLICIES = ("wave", "random")


class RandomPolicy:
    """Uniformly random actions from the env's action space, seeded per episode."""

    def __init__(self, env):
        self.space = env.action_space

    def reset(self, seed: int | None = None) -> None:
        self.space.seed(seed)

    def __call__(self, observation):
        return self.space.sample()


class _Unseeded:
    """Adapts a deterministic policy whose ``reset()`` takes no seed."""

    def __init__(self, policy):
        self.policy = policy

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset()

    def __call__(self, observation):
        return self.policy(observation)


def check_policy_name(name: str) -> str:
    """``name`` if it names a policy, else a ValueError that lists the choices."""
    if name not in SCRIPTED_POLICIES:
        raise ValueError(f"policy must be one of {SCRIPTED_POLICIES}, got {name!r}")
    return name


def make_policy(name: str, env):
    """The policy called ``name`` ("wave": the paper's hand-crafted policy; "random") for ``env``."""
    check_policy_name(name)
    if name == "wave":
        from dpr.policies.wave import WavePolicy

        return _Unseeded(WavePolicy.from_env(env))
    return RandomPolicy(env)

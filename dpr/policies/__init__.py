"""Scripted policies: the paper's wave policy and a random baseline, and policies by name."""

from dpr.policies.registry import SCRIPTED_POLICIES, RandomPolicy, make_policy
from dpr.policies.wave import WavePolicy

__all__ = ["SCRIPTED_POLICIES", "RandomPolicy", "WavePolicy", "make_policy"]

"""Scripted policies: the paper's wave policy and a random baseline, and policies by name."""

from dpr.policies.registry import SCRIPTED_POLICIES, RandomPolicy, make_policy
from dpr.policies.wave import MarkovWavePolicy, WavePolicy

__all__ = ["SCRIPTED_POLICIES", "MarkovWavePolicy", "RandomPolicy", "WavePolicy", "make_policy"]

"""Scripted policies: the paper's wave policy and a random baseline."""

from dpr.policies.wave import WavePolicy

__all__ = ["WavePolicy"]

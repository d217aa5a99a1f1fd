"""Imitation learning: behaviour cloning of recorded demonstrations into the SB3 policy that RL fine-tunes."""

from dpr.imitation.bc import BCResult, behaviour_clone

__all__ = ["BCResult", "behaviour_clone"]

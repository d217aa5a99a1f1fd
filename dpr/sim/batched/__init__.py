"""The disk robot model for K swarms at once, in torch (CPU or CUDA), checked against the pymunk reference
(:mod:`dpr.sim.disk`) by ``tools/batched_agreement.py``."""

from dpr.sim.batched.world import (
    DYNAMICS,
    BatchedDiskWorld,
    SolverSettings,
    checked_size,
    compiled_if,
    estimated_memory,
)

__all__ = ["DYNAMICS", "BatchedDiskWorld", "SolverSettings", "checked_size", "compiled_if", "estimated_memory"]

"""Exploration for fine-tuning: an actor's action distribution widened while its likeliest action stays.

torch and stable-baselines3 are imported inside the function, as in :mod:`dpr.policies.sb3`.
"""

from __future__ import annotations

import math

__all__ = ["soften_actions"]


def soften_actions(policy, temperature: float) -> None:
    """Widen the action distribution of ``policy`` by ``temperature`` (> 1) while its most likely action stays the
    same: logits (Bernoulli and categorical actions) are divided by it, a Gaussian's standard deviation multiplied.

    An actor that PPO trained long is nearly deterministic (a swarm actor's Bernoulli entropy falls to a few
    hundredths of a nat per robot), so a fine-tune from it samples almost only its own actions and has little to
    learn from on new dynamics; softened, it explores again and acts, deterministically, as before."""
    import torch
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from torch import nn

    if temperature == 1.0:
        return
    with torch.no_grad():
        if isinstance(policy.action_dist, DiagGaussianDistribution):
            policy.log_std.add_(math.log(temperature))
            return
        # the logits' last linear layer: SB3's action_net, or the swarm actor's shared per-robot unit
        linear = [module for module in policy.action_net.modules() if isinstance(module, nn.Linear)]
        if not linear:
            raise ValueError(f"{type(policy).__name__}: no linear layer makes its action logits")
        linear[-1].weight.div_(temperature)
        if linear[-1].bias is not None:
            linear[-1].bias.div_(temperature)

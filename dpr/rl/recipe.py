"""The fine-tuning recipe that the pipeline (:mod:`dpr.pipeline.campaign`) and the single commands (``dpr finetune``)
share, so that a fine-tuning run by hand is the pipeline's without restating it.

- The network: a fine-tuning run loads the clone's weights, so it must build the network the clone was built with.
  A model file records it (:attr:`dpr.policies.model_file.ModelInfo.architecture`, e.g. ``SwarmPolicy``, the pipeline's
  actor and ``dpr bc``'s default), and :func:`finetune_defaults` builds it again.
- The discount: the yaml's ``gamma`` is per *decision*. A model deciding every ``action_repeat`` = K physics steps
  discounts :data:`PHYSICS_DISCOUNT` per physics step instead, ``gamma = 0.99**K`` per decision
  (:func:`physics_discount`), so that its horizon is the same simulated time whatever K is.
- The rollouts: deciding every 10 physics steps, an episode holds ten times fewer decisions, so PPO's rollouts are
  shorter and its updates more (:data:`FINETUNE_AT_REPEAT`, over the yaml's ``finetune`` entry).
- The critic warm-up of ``dpr finetune``: a tenth of the fine-tuning steps, at most 10,000
  (:func:`default_critic_warmup`; the presets' ``critic_warmup`` is 10,000 too, though the pipeline counts it in
  physics steps and ``dpr finetune`` in env steps, that is decisions).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from dpr.policies.model_file import PPO

if TYPE_CHECKING:
    from dpr.policies.model_file import ModelInfo

# fine-tuning when deciding every 10 physics steps: shorter rollouts and more epochs than the yaml's entry
FINETUNE_AT_REPEAT = {"n_steps": 512, "batch_size": 128, "n_epochs": 10}
# The yaml's discount is per decision; fine-tuning discounts this much per *physics* step, gamma = 0.99**K per
# decision of K steps (unless finetune_hyperparams sets gamma), so that its horizon is the same simulated time
# whatever K is
PHYSICS_DISCOUNT = 0.99
# The longest default critic warm-up, in env steps
MAX_CRITIC_WARMUP = 10_000


def physics_discount(decision_steps: int) -> float:
    """The discount per decision of ``decision_steps`` physics steps that is PHYSICS_DISCOUNT per physics step."""
    return round(PHYSICS_DISCOUNT**decision_steps, 3)


def finetune_defaults(info: ModelInfo, algo: str | None = None) -> dict[str, Any]:
    """The hyperparameter overrides that fine-tuning the model ``info`` describes with ``algo`` (default: the
    model's own) takes unless told otherwise (``dpr finetune --from MODEL``; a ``--hyperparam`` of the same name
    wins): the network it was built with, when its file records it, and, when it decides every ``action_repeat`` =
    K > 1 physics steps, the discount :func:`physics_discount` (K) and, for PPO, :data:`FINETUNE_AT_REPEAT` (PPO's
    rollout and update sizes; A2C has no batches or epochs)."""
    defaults: dict[str, Any] = {}
    if info.architecture is not None:
        defaults["policy"] = info.architecture["policy"]
        defaults["policy_kwargs"] = dict(info.architecture["policy_kwargs"])
    repeat = info.env_kwargs.get("action_repeat", 1)
    if isinstance(repeat, int) and not isinstance(repeat, bool) and repeat > 1:
        defaults["gamma"] = physics_discount(repeat)
        if (algo or info.algo) == PPO:
            defaults.update(FINETUNE_AT_REPEAT)
    return defaults


def default_critic_warmup(timesteps: int) -> int:
    """The critic warm-up of a fine-tuning run of ``timesteps`` steps: a tenth of them, at most
    :data:`MAX_CRITIC_WARMUP`."""
    return min(timesteps // 10, MAX_CRITIC_WARMUP)

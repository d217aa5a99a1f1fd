"""Policies: the scripted ones (the paper's wave policy, its decentralised form and a random baseline), policies by
name, and the SB3 models that learning trains (:mod:`dpr.policies.sb3`: building, saving, loading;
:mod:`dpr.policies.model_file`: what a model file says about how it was trained; :mod:`dpr.policies.hyperparams`:
what they are built from). The SB3 modules are not imported here: scripted policies must not pay for torch."""

from dpr.policies.decentralised import DecentralisedWavePolicy, PerRobotPolicyAdapter
from dpr.policies.registry import SCRIPTED_POLICIES, RandomPolicy, make_policy
from dpr.policies.wave import MarkovWavePolicy, WavePolicy

__all__ = [
    "SCRIPTED_POLICIES",
    "DecentralisedWavePolicy",
    "MarkovWavePolicy",
    "PerRobotPolicyAdapter",
    "RandomPolicy",
    "WavePolicy",
    "make_policy",
]

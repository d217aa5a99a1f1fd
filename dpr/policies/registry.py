"""Policies by name: what ``dpr evaluate`` and ``dpr collect`` accept as ``--policy``.

A name is a scripted policy (:data:`SCRIPTED_POLICIES`) or the path of a model file ending in ``.zip``
written by ``dpr train`` (loaded by :mod:`dpr.policies.sb3`, which imports stable-baselines3 lazily). The two
waves take their hold and bin width in the name: ``wave-markov:hold_steps=7`` holds each phase 7 steps instead of
the robot model's default (:data:`dpr.policies.wave.MODEL_DEFAULTS`), ``wave-markov:hold_steps=6,bin_width=50``
also bins the robots 50 units wide instead of 60.

Every policy made here is a callable ``policy(observation) -> action`` with ``reset(seed)``, called once
per episode right after ``env.reset(seed=seed)``.
"""

from __future__ import annotations

import json
from pathlib import Path

from dpr.checks import check_number

WAVE = "wave"  # the paper's hand-crafted policy
WAVE_MARKOV = "wave-markov"  # the same wave, its phase read from the observation: an expert imitation can copy
RANDOM = "random"
DECENTRALISED_WAVE = "decentralised-wave"  # every robot runs the wave from its own local observation
SCRIPTED_POLICIES = (WAVE, WAVE_MARKOV, RANDOM, DECENTRALISED_WAVE)
HOLD_PARAMETER = "hold_steps"  # the settings a wave's name carries: wave-markov:hold_steps=7,bin_width=50
BIN_WIDTH_PARAMETER = "bin_width"


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


def wave_name(base: str, hold_steps: int, bin_width: float | None = None) -> str:
    """The name of the wave ``base`` ("wave" or "wave-markov") holding each phase ``hold_steps`` steps, its bins
    ``bin_width`` units wide (None: the wave's 60)."""
    name = f"{base}:{HOLD_PARAMETER}={hold_steps}"
    return name if bin_width is None else f"{name},{BIN_WIDTH_PARAMETER}={bin_width:g}"


N_PHASES_PARAMETER = "n_phases"
# The settings each scripted policy's name may carry, in the order they are listed.
POLICY_SETTINGS = {
    WAVE: (HOLD_PARAMETER, BIN_WIDTH_PARAMETER),
    WAVE_MARKOV: (HOLD_PARAMETER, BIN_WIDTH_PARAMETER),
    DECENTRALISED_WAVE: (HOLD_PARAMETER, N_PHASES_PARAMETER),
}
_EXAMPLES = {
    WAVE: "'wave:hold_steps=7'",
    WAVE_MARKOV: f"{wave_name(WAVE_MARKOV, 7)!r} or {wave_name(WAVE_MARKOV, 6, 50)!r}",
    DECENTRALISED_WAVE: "'decentralised-wave:n_phases=6'",
}


def parse_scripted_name(name: str) -> tuple[str, dict[str, float]]:
    """("wave-markov", {"hold_steps": 7}) from "wave-markov:hold_steps=7" (and "bin_width": 50.0 from
    ",bin_width=50"; "decentralised-wave:n_phases=6" gives {"n_phases": 6}); a plain name has no settings. A
    ValueError names what is wrong: an unknown policy, a setting on a policy without settings, an unknown setting,
    a bad hold, bin width or number of phases."""
    base, colon, text = name.partition(":")
    if base not in SCRIPTED_POLICIES:
        raise ValueError(f"policy must be one of {SCRIPTED_POLICIES} or a path to a .zip model, got {name!r}")
    if not colon:
        return base, {}
    if base not in POLICY_SETTINGS:
        takers = ", ".join(map(repr, POLICY_SETTINGS))
        raise ValueError(f"policy {name!r}: only {takers} take settings, written {_EXAMPLES[WAVE_MARKOV]}")
    from dpr.envs.particle_env import HELD_STEPS_CAP

    allowed = POLICY_SETTINGS[base]
    settings: dict[str, float] = {}
    for setting in text.split(","):
        key, _, value = setting.partition("=")
        if key not in allowed or key in settings:
            raise ValueError(
                f"policy {name!r}: the settings are {' and '.join(allowed)}, each once, written {_EXAMPLES[base]}"
            )
        if key == BIN_WIDTH_PARAMETER:
            try:  # the check WavePolicy and the pipeline's teacher_bin_widths make
                settings[key] = check_number(BIN_WIDTH_PARAMETER, float(value), above=0)
            except ValueError:
                problem = f"{BIN_WIDTH_PARAMETER} must be a number > 0, got {value!r}"
                raise ValueError(f"policy {name!r}: {problem}") from None
            continue
        if key == N_PHASES_PARAMETER:
            if not value.isdigit() or int(value) < 2:
                raise ValueError(f"policy {name!r}: {N_PHASES_PARAMETER} must be an integer >= 2, got {value!r}")
            settings[key] = int(value)
            continue
        cap = HELD_STEPS_CAP if base == WAVE_MARKOV else None  # the Markov wave reads its hold from the observation
        if not value.isdigit() or int(value) < 1 or (cap is not None and int(value) > cap):
            bound = f" and <= {cap}" if cap is not None else ""
            raise ValueError(f"policy {name!r}: {HOLD_PARAMETER} must be an integer >= 1{bound}, got {value!r}")
        settings[key] = int(value)
    return base, settings


def check_policy_name(name: str) -> str:
    """``name`` if it names a policy (a model file must exist and carry its env metadata), else a
    ValueError that lists the choices."""
    from dpr.policies.model_file import is_model_path, read_model_info

    if is_model_path(name):
        read_model_info(name)
        return name
    refuse_lerobot_policy(name)
    parse_scripted_name(name)
    return name


# What LeRobot's save_pretrained writes: a policy folder dpr cannot run without LeRobot (dpr does not import it)
LEROBOT_POLICY_FILES = ("config.json", "model.safetensors")
LEROBOT_RUN_FOLDER = Path("checkpoints") / "last" / "pretrained_model"
LEROBOT_ENV_FILE = "dpr_env.json"  # beside a shipped LeRobot policy: the env id and kwargs it was trained on


def lerobot_policy_type(folder: Path) -> str:
    """The LeRobot policy type (``diffusion``, ``act``, ...) its ``config.json`` in ``folder`` names; "?" where it
    cannot be read."""
    try:
        return json.loads((folder / "config.json").read_text()).get("type", "?")
    except (OSError, ValueError, AttributeError):
        return "?"


def refuse_lerobot_policy(name: str) -> None:
    """A LeRobot policy folder (or a ``lerobot-train`` output folder) as ``--policy``: a ValueError that says how
    to score it, since its network is LeRobot's code and dpr does not depend on LeRobot. Anything else passes."""
    folder = Path(name)
    if (folder / LEROBOT_RUN_FOLDER).is_dir():
        folder = folder / LEROBOT_RUN_FOLDER
    if not all((folder / file).is_file() for file in LEROBOT_POLICY_FILES):
        return
    kind = lerobot_policy_type(folder)
    raise ValueError(
        f"policy {name!r} is a LeRobot policy ({kind}): its network is LeRobot's code, which dpr does not depend on. "
        f"Build LeRobot's side environment with `make lerobot-env`, then score it there with dpr's metrics: "
        f".venv-lerobot/bin/python tools/lerobot_policies.py evaluate --model {name} --seeds 320-339 --json OUT.json "
        "(docs/lerobot-policies.md)"
    )


def make_policy(name: str, env, transfer: bool = False):
    """The policy called ``name`` for ``env``: "wave" (the paper's hand-crafted policy, phases held a fixed
    number of steps), "wave-markov" (the same wave with its phase read from the observation, which imitation
    can reproduce), either with another hold or bin width ("wave-markov:hold_steps=6,bin_width=50"), "random",
    "decentralised-wave" (every robot decides from its own local observation and a shared clock,
    :mod:`dpr.policies.decentralised`; "decentralised-wave:n_phases=6" runs six phases a cycle), or a ``.zip``
    model file trained on ``env``'s id and spaces (with ``transfer``, on any task with ``env``'s spaces); a per-robot
    model file (:mod:`dpr.policies.per_robot_model`) runs at any swarm size."""
    check_policy_name(name)
    from dpr.policies.model_file import is_model_path, read_model_info
    from dpr.policies.sb3 import load_model_policy

    if is_model_path(name):
        if read_model_info(name).per_robot is not None:  # one robot's model: every robot of any N runs it
            from dpr.policies.per_robot_model import per_robot_model_policy

            return per_robot_model_policy(name, env)
        return load_model_policy(name, env, transfer)
    name, settings = parse_scripted_name(name)
    if name == WAVE:
        from dpr.policies.wave import WavePolicy

        return _Unseeded(WavePolicy.from_env(env, **settings))
    if name == WAVE_MARKOV:
        from dpr.policies.wave import MarkovWavePolicy

        return _Unseeded(MarkovWavePolicy.from_env(env, **settings))
    if name == DECENTRALISED_WAVE:
        from dpr.policies.decentralised import DecentralisedWavePolicy

        return DecentralisedWavePolicy.for_env(env, **settings)
    return RandomPolicy(env)

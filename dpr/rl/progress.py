"""What a training run shows while it learns: a progress bar over the steps its budget counts (SB3's own, or a
per-robot run's swarm steps), and whether tensorboard is there to log to."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

from dpr.interrupts import raise_if_interrupted


def tensorboard_available() -> bool:
    return importlib.util.find_spec("tensorboard") is not None


@dataclass(frozen=True)
class StepUnit:
    """The steps a run's budget counts, against SB3's ``num_timesteps`` (which grows by the VecEnv's ``num_envs``
    at every step of the vector): one vector step is ``sb3_steps`` of SB3's and ``counted`` of the run's.
    Centralised runs count SB3's own steps (:data:`SB3_STEPS`); a per-robot run, whose VecEnv entries are
    robots, counts swarm steps (:mod:`dpr.rl.finetune_per_robot`)."""

    sb3_steps: int = 1
    counted: int = 1

    def to_sb3(self, steps: int) -> int:
        """SB3's ``total_timesteps`` for ``steps`` counted steps (whole vector steps, rounded up)."""
        return -(-steps // self.counted) * self.sb3_steps

    def from_sb3(self, timesteps: int) -> int:
        """The counted steps in ``timesteps`` of SB3's."""
        return timesteps // self.sb3_steps * self.counted


SB3_STEPS = StepUnit()


def progress_bar(desc: str, total: int, show_progress: bool, unit: StepUnit = SB3_STEPS, origin: int | None = None):
    """An SB3 callback showing a tqdm bar over the ``total`` steps (counted in ``unit``) of one ``learn`` call
    (counted from where the model's step count stood, so a run after a critic warm-up starts at 0; or from
    ``origin``, where a resumed run's first ``learn`` call started), with the mean return of the last episodes. It
    also stops training at a Ctrl-C that was swallowed (:func:`dpr.interrupts.raise_if_interrupted`)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class ProgressBar(BaseCallback):
        def _on_training_start(self) -> None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="step", disable=not show_progress)
            self.first_step = self.model.num_timesteps if origin is None else origin

        def _on_step(self) -> bool:
            raise_if_interrupted()  # a Ctrl-C swallowed by a callback from C code (dpr.interrupts) stops here
            done = unit.from_sb3(self.model.num_timesteps - self.first_step)
            self.bar.update(min(done, total) - self.bar.n)  # SB3 ends with a whole rollout, past the total
            if self.model.ep_info_buffer and self.n_calls % 100 == 0:
                mean = sum(e["r"] for e in self.model.ep_info_buffer) / len(self.model.ep_info_buffer)
                self.bar.set_postfix(ep_rew_mean=f"{mean:.3g}", refresh=False)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return ProgressBar()

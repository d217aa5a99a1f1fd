"""What a `dpr collect` run records and did: :class:`EpisodeRecord` (one rolled-out episode, on either engine),
:class:`CollectSummary` and the text the command prints of it."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from dpr.datasets import features as F
from dpr.metrics import EpisodeMetrics


@dataclass
class EpisodeRecord:
    """One rolled-out episode as arrays (``T`` frames), with what is needed to replay it."""

    seed: int
    observations: np.ndarray  # [T, D] float32
    actions: np.ndarray  # [T, N] float32 or [T, 1] int64
    rewards: np.ndarray  # [T] float32
    dones: np.ndarray  # [T] bool
    successes: np.ndarray  # [T] bool
    metrics: EpisodeMetrics
    images: np.ndarray | None = None  # [T, H, W, 3] uint8
    environment_states: np.ndarray | None = None  # [T, E] float32: the env's environment_state() at each frame
    physics_error: str | None = None
    seconds: float = 0.0
    trajectory: np.ndarray | None = None  # [T + 1, 2] the agent's positions (what the metrics are computed from)

    @property
    def frames(self) -> int:
        return len(self.actions)


@dataclass
class RecordedFrames:
    """What an episode's frames gather as it runs, one entry a frame, on either engine. Environment states are taken
    before each step, so after a physics error they hold one more (the state the blown-up, unrecorded step started
    from)."""

    observations: list = field(default_factory=list)
    actions: list = field(default_factory=list)
    dones: list = field(default_factory=list)
    successes: list = field(default_factory=list)
    environment_states: list = field(default_factory=list)

    def arrays(self, env) -> dict[str, np.ndarray]:
        """The frames as the arrays of an :class:`EpisodeRecord` (``env``: a single env, unwrapped, whose
        ``action_type``, ``n_robots``, ``state_size`` and ``environment_state_names`` shape them)."""
        frames = len(self.actions)
        discrete = env.action_type == "discrete"
        return {
            "observations": np.array(self.observations, dtype=np.float32).reshape(frames, env.state_size),
            "actions": np.array(self.actions, dtype=np.int64 if discrete else np.float32).reshape(
                frames, 1 if discrete else env.n_robots
            ),
            "dones": np.array(self.dones, dtype=bool),
            "successes": np.array(self.successes, dtype=bool),
            "environment_states": np.array(self.environment_states[:frames], dtype=np.float32).reshape(
                frames, len(env.environment_state_names)
            ),
        }


@dataclass
class CollectSummary:
    root: str
    env_id: str
    policy: str
    episodes_before: int
    episodes_added: int
    episodes_total: int
    frames_added: int
    frames_total: int
    seconds: float
    bytes_written: int  # the dataset's growth: negative when a compaction freed more than was added
    interrupted: bool
    metrics: dict  # median / min / max of each metric over the added episodes, and the success rate

    def as_dict(self) -> dict:
        return asdict(self)


def folder_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) if root.exists() else 0


_DISTANCES = tuple(name for name in F.METRIC_FIELDS if name != "success")


def metric_summary(records: list) -> dict:
    """Median, min and max of each distance over ``records`` (saved episodes), and their success rate."""
    if not records:
        return {}
    out = {}
    for name in _DISTANCES:
        values = np.array([getattr(r.metrics, name) for r in records])
        out[name] = {"median": float(np.median(values)), "min": float(values.min()), "max": float(values.max())}
    out["success_rate"] = float(np.mean([r.metrics.success for r in records]))
    return out


def format_summary(summary: CollectSummary) -> str:
    lines = [
        f"dataset     {summary.root}  ({summary.env_id}, policy {summary.policy})",
        f"episodes    {summary.episodes_added} added, {summary.episodes_total} in total"
        + ("  (interrupted: run the same command again to resume)" if summary.interrupted else ""),
        f"frames      {summary.frames_added} added, {summary.frames_total} in total",
        f"{'written' if summary.bytes_written >= 0 else 'freed':<12s}{_human_bytes(abs(summary.bytes_written))} "
        f"in {summary.seconds:.1f} s"
        + (f" ({summary.frames_added / summary.seconds:.0f} frames/s)" if summary.seconds > 0 else ""),
    ]
    if summary.metrics:
        m = summary.metrics
        lines.append(f"success     {m['success_rate']:.0%}")
        for name in _DISTANCES:
            s = m[name]
            lines.append(f"{name:<24s} median {s['median']:.1f}  min {s['min']:.1f}  max {s['max']:.1f}")
    return "\n".join(lines)


def _human_bytes(n: int) -> str:
    if n < 1024:
        return f"{n} B"
    exponent = min(int(math.log(n, 1024)), 4)
    return f"{n / 1024**exponent:.1f} {'BKMGT'[exponent]}{'iB' if exponent else ''}"

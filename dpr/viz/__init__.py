"""Episode inspection in rerun: logged from MCAP files, LeRobot datasets or live policy rollouts.

``dpr view`` (see :mod:`dpr.cli`) is the front end. Loading (:mod:`dpr.viz.episodes`) turns each source into an
:class:`EpisodeLog` of plain arrays; :mod:`dpr.viz.rerun_log` logs those with one ``send_columns`` call per
entity and builds a blueprint with one scene view per episode above shared metric plots. Nothing else in
``dpr`` imports this package.
"""

from dpr.viz.episodes import (
    EpisodeLog,
    ViewError,
    ViewParameterError,
    ViewRollout,
    check_view_policy,
    episode_from_dataset,
    episode_from_mcap,
    rollout_episode,
    running_metrics,
)
from dpr.viz.rerun_log import METRICS, log_episode, make_blueprint, save_rrd, serve, spawn_viewer

__all__ = [
    "METRICS",
    "EpisodeLog",
    "ViewError",
    "ViewParameterError",
    "ViewRollout",
    "check_view_policy",
    "episode_from_dataset",
    "episode_from_mcap",
    "log_episode",
    "make_blueprint",
    "rollout_episode",
    "running_metrics",
    "save_rrd",
    "serve",
    "spawn_viewer",
]

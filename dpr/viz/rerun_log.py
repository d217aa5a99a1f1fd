"""Log :class:`~dpr.viz.episodes.EpisodeLog` episodes to rerun, with a blueprint that shows them side by side.

Entities of an episode named ``NAME`` (one subtree per episode or policy)::

    /NAME/scene                     static Transform3D scale (1, -1, 1): the world's y points up, rerun's 2D y down
    /NAME/scene/robots              Points2D per step: robot centres, radius following the expansion,
                                    dead robots red
    /NAME/scene/magnets             LineStrips2D per step, one segment per active magnet (MCAP and live rollouts)
    /NAME/scene/centre_of_mass      Points2D per step (the blueprint shows it as a trail up to the time cursor)
    /NAME/scene/path                static LineStrips2D: the agent's whole trajectory
    /NAME/scene/goal                static Points2D, radius = the success radius
    /NAME/scene/walls               static LineStrips2D, closed polygons (Gate)
    /NAME/scene/object              Points2D (ball) or LineStrips2D (box outline) per step (Manipulation)
    /NAME/metrics/reward            Scalars, states 1 .. S-1 (the reward of the env step that led to the state)
    /NAME/metrics/distance_to_goal, projected_displacement, net_displacement, total_distance
                                    Scalars, states 0 .. S-1 (the agent's metrics so far, see dpr.metrics)

Timelines: ``step`` (sequence: the physics step) and ``sim_time`` (duration: simulated time, 0.1 s a physics
step). A policy that decides every k physics steps logs its state at every decision, on steps 0, k, 2k, ...: episodes
side by side share one clock. Per-state data goes out with one ``send_columns`` call per entity for the whole
episode, never one ``log`` call per step.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dpr.atomic import AtomicFile
from dpr.checks import ParameterError
from dpr.envs.rendering import BODY, DEAD_BODY, GOAL, MAGNET, OBJECT, WALL
from dpr.metrics import SUCCESS_RADIUS
from dpr.sim.constants import FPS
from dpr.viz.episodes import STEP_NS, EpisodeLog, ViewError

APPLICATION_ID = "dpr"
STEP = "step"
SIM_TIME = "sim_time"
METRICS = ("reward", "distance_to_goal", "projected_displacement", "net_displacement", "total_distance")
SCENE_ENTITIES = ("robots", "magnets", "centre_of_mass", "path", "goal", "walls", "object")
# one colour per episode in the shared metric plots
SERIES_COLORS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))
PATH_COLOR = (150, 150, 150)
COM_COLOR = (20, 20, 20)
MAGNET_WIDTH = 1.5  # line radii in world units
WALL_WIDTH = 2.0
PATH_WIDTH = 1.0
COM_RADIUS = 4.0
BOUNDS_MARGIN = 60.0  # world units around everything the scene holds


def _time_columns(steps: np.ndarray) -> list[rr.TimeColumn]:
    """``step`` and ``sim_time`` of states at physics steps ``steps``."""
    # integer nanoseconds: step * 0.1 s computed in floats can land a nanosecond short
    nanos = steps.astype(np.int64) * STEP_NS
    return [
        rr.TimeColumn(STEP, sequence=steps),
        rr.TimeColumn(SIM_TIME, duration=nanos.astype("timedelta64[ns]")),
    ]


def _box_outlines(poses: np.ndarray, half_side: float) -> np.ndarray:
    """[S, 5, 2] closed outlines of squares of half side ``half_side`` at ``poses`` [S, 3] (x, y, angle)."""
    corners = np.array([(-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1)], dtype=np.float64) * half_side
    cos, sin = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + cos * corners[:, 0] - sin * corners[:, 1]
    y = poses[:, 1:2] + sin * corners[:, 0] + cos * corners[:, 1]
    return np.stack([x, y], axis=-1)


def log_episode(recording: rr.RecordingStream, episode: EpisodeLog, color: Sequence[int] = SERIES_COLORS[0]) -> None:
    """Log ``episode`` under ``/<episode.name>`` of ``recording`` (see the module docstring for the entities)."""
    base = f"/{episode.name}"
    scene = f"{base}/scene"
    steps = episode.steps
    times = _time_columns(steps)
    s, n = episode.n_states, episode.n_robots

    recording.log(scene, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    recording.log(
        f"{scene}/goal", rr.Points2D([episode.goal], radii=SUCCESS_RADIUS, colors=[GOAL], labels=["goal"]), static=True
    )
    if episode.walls:
        recording.log(f"{scene}/walls", rr.LineStrips2D(episode.walls, radii=WALL_WIDTH, colors=[WALL]), static=True)
    recording.log(f"{scene}/path", rr.LineStrips2D([episode.agent], radii=PATH_WIDTH, colors=[PATH_COLOR]), static=True)

    robot_colors = np.where(episode.alive[:, None], np.array(BODY, np.uint8), np.array(DEAD_BODY, np.uint8))
    recording.send_columns(
        f"{scene}/robots",
        indexes=times,
        columns=rr.Points2D.columns(
            positions=episode.positions.reshape(-1, 2),
            radii=episode.radii().reshape(-1).astype(np.float32),
            colors=np.tile(robot_colors, (s, 1)),
        ).partition(np.full(s, n)),
    )
    recording.send_columns(
        f"{scene}/centre_of_mass",
        indexes=times,
        columns=rr.Points2D.columns(
            positions=episode.centres_of_mass,
            radii=np.full(s, COM_RADIUS, np.float32),
            colors=np.tile(np.array(COM_COLOR, np.uint8), (s, 1)),
        ),
    )
    if episode.magnets is not None:
        _send_magnets(recording, f"{scene}/magnets", times, episode.magnets)
    if episode.object_poses is not None:
        _send_object(recording, f"{scene}/object", times, episode)

    rewards_times = _time_columns(steps[1:])
    name = rr.SeriesLines(names=[episode.title or episode.name], colors=[color])
    recording.log(f"{base}/metrics/reward", name, static=True)
    recording.send_columns(
        f"{base}/metrics/reward", indexes=rewards_times, columns=rr.Scalars.columns(scalars=episode.rewards)
    )
    for key, values in episode.running_metrics().items():
        recording.log(f"{base}/metrics/{key}", name, static=True)
        recording.send_columns(f"{base}/metrics/{key}", indexes=times, columns=rr.Scalars.columns(scalars=values))


def _send_magnets(recording: rr.RecordingStream, path: str, times: list, magnets: list[np.ndarray]) -> None:
    """One row per step holding that step's magnets: a variable number of 2-point strips."""
    counts = np.array([len(m) for m in magnets], dtype=np.int64)
    segments = np.concatenate(magnets) if counts.sum() else np.zeros((0, 2, 2))
    recording.send_columns(
        path,
        indexes=times,
        columns=rr.LineStrips2D.columns(
            strips=segments,
            radii=np.full(len(segments), MAGNET_WIDTH, np.float32),
            colors=np.tile(np.array(MAGNET, np.uint8), (len(segments), 1)),
        ).partition(counts),
    )


def _send_object(recording: rr.RecordingStream, path: str, times: list, episode: EpisodeLog) -> None:
    poses = episode.object_poses
    size = float(episode.object_size or 0.0)
    s = len(poses)
    color = np.tile(np.array(OBJECT, np.uint8), (s, 1))
    if episode.object_kind == "box":
        columns = rr.LineStrips2D.columns(
            strips=_box_outlines(poses, size), radii=np.full(s, 2.0, np.float32), colors=color
        )
    else:
        columns = rr.Points2D.columns(positions=poses[:, 0:2], radii=np.full(s, size, np.float32), colors=color)
    recording.send_columns(path, indexes=times, columns=columns)


# -- blueprint -----------------------------------------------------------------------------------------------
def scene_bounds(episodes: Sequence[EpisodeLog]) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x_range, y_range) in world units holding every robot, the goal and every wall of ``episodes``."""
    points = [e.positions.reshape(-1, 2) for e in episodes] + [e.goal[None] for e in episodes]
    points += [wall for e in episodes for wall in e.walls]
    stacked = np.concatenate(points)
    stacked = stacked[np.isfinite(stacked).all(axis=1)]
    reach = max(max(e.robot_radii) for e in episodes) + BOUNDS_MARGIN
    (x0, y0), (x1, y1) = stacked.min(axis=0) - reach, stacked.max(axis=0) + reach
    return (float(x0), float(x1)), (float(y0), float(y1))


def make_blueprint(episodes: Sequence[EpisodeLog]) -> rrb.Blueprint:
    """Scene views in a grid (one per episode, all with the same bounds) above one plot per metric that
    overlays the episodes."""
    (x0, x1), (y0, y1) = scene_bounds(episodes)
    bounds = rrb.VisualBounds2D(x_range=[x0, x1], y_range=[-y1, -y0])  # view space has y flipped
    trail = rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
            )
            for timeline in (STEP, SIM_TIME)
        ]
    )
    scenes = [
        rrb.Spatial2DView(
            origin=f"/{e.name}",
            contents="$origin/scene/**",
            name=e.title or e.name,
            visual_bounds=bounds,
            overrides={f"/{e.name}/scene/centre_of_mass": trail},
        )
        for e in episodes
    ]
    plots = [
        rrb.TimeSeriesView(origin="/", contents=[f"/{e.name}/metrics/{key}" for e in episodes], name=key)
        for key in METRICS
    ]
    columns = min(len(scenes), 3)
    return rrb.Blueprint(
        rrb.Vertical(rrb.Grid(*scenes, grid_columns=columns), rrb.Horizontal(*plots), row_shares=[3, 2]),
        rrb.TimePanel(timeline=STEP, fps=float(FPS)),  # physics steps per second: plays in simulated time
        collapse_panels=False,
    )


# -- sinks ---------------------------------------------------------------------------------------------------
def check_unique_names(episodes: Sequence[EpisodeLog]) -> None:
    names = [e.name for e in episodes]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ViewError(f"two episodes would share the entity subtree(s) {twice}; list each one once")
    if not episodes:
        raise ViewError("nothing to show: no episodes")


def new_recording(title: str) -> rr.RecordingStream:
    """A recording of its own (not rerun's global one), so several can be made in one process."""
    recording = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    recording.send_recording_name(title)
    return recording


def log_all(recording: rr.RecordingStream, episodes: Sequence[EpisodeLog]) -> None:
    for index, episode in enumerate(episodes):
        log_episode(recording, episode, SERIES_COLORS[index % len(SERIES_COLORS)])


class SavePathError(ViewError, ParameterError):
    """A ``path`` that :func:`save_rrd` cannot write: a :class:`ViewError` (what the viewer's callers catch) and a
    :class:`~dpr.checks.ParameterError` naming the parameter (``path``), which the CLI says as its own flag."""


def save_rrd(episodes: Sequence[EpisodeLog], path: str | os.PathLike, title: str = "dpr view") -> Path:
    """Write ``episodes`` and their blueprint to a new ``.rrd`` file. The data goes to a temporary file beside
    ``path`` (:class:`dpr.atomic.AtomicFile`) that is fsynced and renamed onto it once complete. An existing
    ``path``, or one that appears while logging, is refused (:class:`SavePathError`), never overwritten."""
    path = Path(path)
    check_unique_names(episodes)
    if path.exists():
        raise SavePathError("path", f"{path} already exists; choose another path (files are never overwritten)")
    if not path.parent.is_dir():
        raise SavePathError("path", f"folder {path.parent} does not exist")
    with AtomicFile(path, exclusive=True) as target:
        recording = new_recording(title)
        # rerun's file sink writes the temporary file by its name; AtomicFile's own handle then fsyncs it
        recording.save(target.temp_path, default_blueprint=make_blueprint(episodes))
        log_all(recording, episodes)
        recording.flush()
        recording.disconnect()  # closes the file sink: everything is in the file after this
        try:
            target.commit()
        except FileExistsError:
            raise SavePathError("path", f"{path} appeared while logging; left it alone") from None
    return path


def _put_viewer_on_path() -> None:
    """rerun spawns the ``rerun`` executable found on PATH. rerun-sdk installs it beside this Python, which is
    not on PATH when ``dpr`` is run as ``.venv/bin/dpr`` without activating the environment."""
    if shutil.which("rerun") is not None:
        return
    beside = Path(sys.executable).parent
    if (beside / "rerun").exists():
        os.environ["PATH"] = f"{beside}{os.pathsep}{os.environ.get('PATH', '')}"


def spawn_viewer(episodes: Sequence[EpisodeLog], title: str = "dpr view") -> None:
    """Start a rerun viewer process and stream ``episodes`` to it."""
    check_unique_names(episodes)
    _put_viewer_on_path()
    recording = new_recording(title)
    recording.spawn(default_blueprint=make_blueprint(episodes))
    log_all(recording, episodes)
    recording.flush()


def serve(episodes: Sequence[EpisodeLog], title: str = "dpr view", port: int | None = None) -> None:
    """Serve ``episodes`` over gRPC until Ctrl-C (the server lives as long as this process)."""
    check_unique_names(episodes)
    recording = new_recording(title)
    uri = recording.serve_grpc(grpc_port=port, default_blueprint=make_blueprint(episodes))
    log_all(recording, episodes)
    recording.flush()
    print(
        f"serving {len(episodes)} episode(s) at {uri}\nopen it with: rerun {uri}   (Ctrl-C stops the server)",
        flush=True,
    )
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        recording.disconnect()

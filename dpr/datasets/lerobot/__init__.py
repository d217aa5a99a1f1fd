"""LeRobot dataset format v3.0: a crash-safe writer and a lazy reader (pyarrow + numpy + json, no ``lerobot``).

A dataset written here loads unchanged in ``lerobot.datasets.lerobot_dataset.LeRobotDataset(repo_id, root=ROOT)``;
the layout is described in the repository's ``docs/lerobot_v3_format.md``, and how this project uses it in
``docs/datasets.md``. Layout::

    ROOT/meta/info.json                                  the commit point (totals, features, fps, ...)
    ROOT/meta/stats.json                                 stats aggregated over the committed episodes
    ROOT/meta/tasks.parquet                              pandas frame indexed by task string, column task_index
    ROOT/meta/episodes/chunk-{c:03d}/file-{f:03d}.parquet  one row per episode (recording: one file per episode)
    ROOT/data/chunk-{c:03d}/file-{f:03d}.parquet           one row per frame (recording: one file per episode)

with ``c, f = divmod(n, 1000)`` for file number ``n``: recording gives each new episode the next number, and
:func:`compact` packs the files into LeRobot's ~100 MB ones (:mod:`.compaction`). ``info.json``'s
``dpr_live_files = [first, end]`` says which numbers hold the dataset. Column types: a shape ``[1]`` feature is
a scalar column, ``[n]`` a ``fixed_size_list<dtype>[n]``, an image a ``struct<bytes: binary, path: string>``
holding a PNG. The five LeRobot default columns (``timestamp = frame_index / fps`` as float32,
``frame_index``, ``episode_index``, ``index``, ``task_index``) are derived here, never supplied.

Crash safety. LeRobot's own writer keeps one parquet file open until ``finalize()``, so a crash loses everything.
Here every :meth:`LeRobotWriter.save_episode` writes the episode's data file and its episodes-meta file, then
``tasks.parquet`` (when a task is new), ``stats.json`` and last ``info.json``; each through :mod:`dpr.atomic` (a
temporary name in the same folder that does not end in ``.parquet``, because LeRobot loads every
``data/*/*.parquet``; fsync; rename; folder fsync). ``info.json`` is the commit point: episodes at or above its
``total_episodes``, and files outside its ``dpr_live_files``, are uncommitted, ignored by :class:`LeRobotReader`
and deleted by :meth:`LeRobotWriter.open`, which then resumes after the last committed episode (:func:`repair`
does the clean-up alone). Only compaction rewrites committed files, and it writes the new ones beside them before
it swaps info.json. LeRobot itself globs every ``data/*/*.parquet``: it would see an uncommitted episode's rows
(or both layouts of an interrupted compaction) until the dataset is opened or repaired.

Modules: :mod:`.format` (paths, info.json, feature specs, :class:`DatasetError`), :mod:`.stats` (statistics),
:mod:`.meta` (episode rows and tasks), :mod:`.checksums` (of the data and the meta tables, checked on every read),
:mod:`.tables` (an episode as arrow tables), :mod:`.files` (writer lock, leftovers), :mod:`.writer`
(:class:`LeRobotWriter`, :func:`repair`, :func:`compact`), :mod:`.compaction` (file packing), :mod:`.reader`
(:class:`LeRobotReader`).
"""

from dpr.datasets.lerobot.format import (
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_PATH,
    EPISODES_PATH,
    IMAGE_STATS_MAX_FRAMES,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    DatasetError,
    default_features,
)
from dpr.datasets.lerobot.reader import LeRobotReader
from dpr.datasets.lerobot.writer import LeRobotWriter, compact, repair

__all__ = [
    "CHUNKS_SIZE",
    "CODEBASE_VERSION",
    "DATA_PATH",
    "EPISODES_PATH",
    "IMAGE_STATS_MAX_FRAMES",
    "INFO_PATH",
    "STATS_PATH",
    "TASKS_PATH",
    "DatasetError",
    "LeRobotReader",
    "LeRobotWriter",
    "compact",
    "default_features",
    "repair",
]

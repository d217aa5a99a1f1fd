"""MCAP logs of swarm episodes: one file per episode, JSON messages described by JSON schemas.

The files open in Foxglove (every field can be plotted, since each channel carries a ``jsonschema`` schema)
and read back with the ``mcap`` library, or with :func:`read_mcap` into numpy arrays.

Layout of a file written by :class:`McapEpisodeWriter` (format ``dpr-mcap/1``)
----------------------------------------------------------------------------------
Log time of step ``t`` is its simulated time, ``t * action_repeat * 0.1 s`` in nanoseconds (an env step is
``action_repeat`` physics steps of 0.1 s; :func:`dpr.envs.particle_env.seconds_per_step`); step 0 is the state
right after ``reset()``, step ``t >= 1`` the state after the ``t``-th ``env.step``.

========================  ============  ===========================================================
topic                     steps         fields
========================  ============  ===========================================================
``/scene``                once, t = 0   ``goal`` [2]; ``walls``: polygons, each a list of [x, y];
                                        ``object``: {``kind``, ``size``} or null;
                                        ``robot_radii``: [contracted, expanded] or null
``/swarm/state``          0 .. T        ``step``, ``time`` (s); per robot lists of N: ``x``, ``y``,
                                        ``angle``, ``vx``, ``vy``, ``omega``, ``expansion`` (0..1),
                                        ``alive`` (bools); ``centre_of_mass`` [2]
``/swarm/magnets``        0 .. T        ``step``, ``segments``: [[x0, y0], [x1, y1]] per active
                          (optional)    magnet, rounded to 0.01 units (a drawing aid, not state;
                                        recorded when step 0 has them, then at every step)
``/object``               0 .. T        ``step``, ``x``, ``y``, ``angle``, ``vx``, ``vy`` (tasks
                          (optional)    with an object; recorded at every step or at none)
``/action``               1 .. T        ``step``, ``action`` [N]: the per-robot expansion targets
                                        passed to ``env.step`` number ``step`` (taken in state
                                        ``step - 1``; a Discrete(2^N) action is stored as its N bits,
                                        robot 0 the most significant)
``/reward``               1 .. T        ``step``, ``reward``, ``terminated``, ``truncated``, and the
                                        episode metrics so far: ``projected_displacement``,
                                        ``net_displacement``, ``total_distance``, ``is_success``
========================  ============  ===========================================================

Episode metadata is an MCAP Metadata record named ``dpr.episode``: ``format`` (``dpr-mcap/1``),
``action_repeat`` (physics steps per env step; a file written before it was recorded logged 0.1 s per env step
whatever the env's was: :func:`read_mcap` then takes the episode's ``env_kwargs``' value for its times) and the
caller's keys (typically ``env_id``, ``seed``, ``n_robots``, ``robot_model``, ``policy``, ``env_kwargs``; see
:func:`episode_metadata`). MCAP metadata values are strings: string values are stored as they are, any
other value as JSON text, and the key ``json_keys`` lists (comma-separated) which keys hold JSON, so
:func:`read_mcap` gives back the original values.

Floats are written with Python's ``repr`` (the shortest text that parses back to the same float64), so a
file reads back bit-exact (all but the magnet end points, which are rounded). JSON has no NaN or infinity:
a message holding one (a physics blow-up) stores ``null`` in its place, which reads back as NaN.

Crash safety: an unfinished episode's log lives in an anonymous spool (memory, then an unlinked temporary
file), so a killed run leaves nothing of it on disk. :meth:`McapEpisodeWriter.close` copies the log into a
temporary file beside the target (``.<name>.<pid>.<random>.dpr-tmp``, see :mod:`dpr.atomic`), fsyncs it and
renames it onto the final name; an exception inside ``with McapEpisodeWriter(...)`` drops the spool.

Modules: :mod:`~dpr.datasets.mcap.schema` (topics, JSON schemas, encoding, :class:`McapError`),
:mod:`~dpr.datasets.mcap.writer` (:class:`McapEpisodeWriter`, logging a live env) and
:mod:`~dpr.datasets.mcap.reader` (:func:`read_mcap`). Import from this package.
"""

from dpr.datasets.mcap.reader import McapEpisode, read_mcap
from dpr.datasets.mcap.schema import (
    MAGNET_DECIMALS,
    MCAP_FORMAT,
    METADATA_NAME,
    METRIC_KEYS,
    REQUIRED_TOPICS,
    SCHEMAS,
    STEP_NS,
    TOPIC_ACTION,
    TOPIC_MAGNETS,
    TOPIC_OBJECT,
    TOPIC_REWARD,
    TOPIC_SCENE,
    TOPIC_STATE,
    McapError,
)
from dpr.datasets.mcap.writer import (
    McapEpisodeWriter,
    StepOutcome,
    SwarmState,
    episode_metadata,
    log_env_scene,
    log_env_step,
)

__all__ = [
    "MAGNET_DECIMALS",
    "MCAP_FORMAT",
    "METADATA_NAME",
    "METRIC_KEYS",
    "REQUIRED_TOPICS",
    "SCHEMAS",
    "STEP_NS",
    "TOPIC_ACTION",
    "TOPIC_MAGNETS",
    "TOPIC_OBJECT",
    "TOPIC_REWARD",
    "TOPIC_SCENE",
    "TOPIC_STATE",
    "McapEpisode",
    "McapEpisodeWriter",
    "McapError",
    "StepOutcome",
    "SwarmState",
    "episode_metadata",
    "log_env_scene",
    "log_env_step",
    "read_mcap",
]

"""A resumable record of finished episodes for the sweep tools: one JSON object per line, keyed by ``key``.

Paddle episodes of hundreds of robots take minutes, so the tools append every finished episode as it ends and a
rerun computes only what is missing. Change the file (or delete it) after changing a model or a policy.
"""

from __future__ import annotations

import json
from pathlib import Path


def load_episodes(path: Path | None) -> dict[str, dict]:
    """Every record in ``path`` by key (empty when there is no file); later lines win."""
    if path is None or not path.exists():
        return {}
    records = {}
    for line in path.read_text().splitlines():
        if line.strip():
            record = json.loads(line)
            records[record["key"]] = record
    return records


def append_episode(path: Path | None, record: dict) -> None:
    """Add one finished episode (a dict with ``key``) to ``path``."""
    if path is not None:
        with path.open("a") as f:
            f.write(json.dumps(record) + "\n")

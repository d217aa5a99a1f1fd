"""The stage scheduler: of the stages ready to build, the one holding up the longest chain of stages goes first."""

import json
import time
from pathlib import Path

from dpr.rl.pipeline import task_stages
from dpr.rl.pipeline_config import load_config
from dpr.rl.stages import Stage, StageStore, chain_lengths, closure, run_stages


def test_a_clone_holds_up_a_longer_chain_than_a_run_from_scratch():
    stages = task_stages(load_config(preset="tiny", tasks=["gate"]), "gate")
    chain = chain_lengths(closure([*stages.models.values(), *stages.evaluations.values()]))
    clone, fine_tuned, scratch = (stages.models[method, 0].key for method in ("bc", "bc-ppo", "ppo"))
    assert chain[clone] == chain[fine_tuned] + 1 and chain[fine_tuned] == chain[scratch] == 2


def _note_start(settings, inputs, out, work, show_progress):
    """A builder that records when it started and takes a moment."""
    (Path(settings["log"]) / settings["name"]).write_text(json.dumps(time.time()))
    time.sleep(0.5)
    (out / "done").write_text("x")


def test_free_workers_take_the_stages_with_the_longest_chains_first(tmp_path):
    """Two workers, three stages ready: a leaf listed first, and two heads of chains. The heads start first."""
    log = tmp_path / "log"
    log.mkdir()

    def stage(name, needs=()):
        return Stage("test", name, {"name": name, "log": str(log)}, _note_start, {n.name: n for n in needs})

    leaf, head, other = stage("leaf"), stage("head"), stage("other")
    tail = stage("tail", [head])
    end = stage("end", [tail, other])
    run_stages([leaf, end], StageStore(tmp_path / "stages"), workers=2, log=lambda line: None)
    started = {name: json.loads((log / name).read_text()) for name in ("leaf", "head", "other", "tail", "end")}
    assert max(started["head"], started["other"]) < started["leaf"]

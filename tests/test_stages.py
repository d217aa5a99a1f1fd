"""The stage scheduler: of the stages ready to build, the one holding up the longest chain of stages goes first."""

import json
import time
from pathlib import Path

from dpr.pipeline.campaign import task_stages
from dpr.pipeline.config import load_config
from dpr.pipeline.stages import Stage, StageStore, chain_lengths, closure, run_stages


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


LONG_STAGES = """
import sys, time
from pathlib import Path
from dpr import interrupts
from dpr.pipeline.stages import Stage, StageStore, run_stages

def wait_for_ctrl_c(settings, inputs, out, work, show_progress):
    marks = Path(settings["marks"])
    (marks / f"{settings['name']}.started").write_text("x")
    try:
        while True:
            time.sleep(0.05)
    except KeyboardInterrupt:
        (marks / f"{settings['name']}.stopped").write_text("x")
        raise

interrupts.install()
marks = Path(sys.argv[1])
stages = [Stage("test", name, {"name": name, "marks": str(marks)}, wait_for_ctrl_c) for name in ("a", "b")]
try:
    run_stages(stages, StageStore(marks / "stages"), workers=2, log=lambda line: None)
except KeyboardInterrupt:
    sys.exit(130)
"""


def test_a_sigint_to_the_run_alone_stops_the_stages_in_flight(tmp_path):
    """``kill -INT`` of the scheduling process (not of its process group, as Ctrl-C at a terminal is): the stages
    in the workers are interrupted too, and the run ends, instead of waiting for them to finish."""
    import signal
    import subprocess
    import sys

    script = tmp_path / "long_stages.py"
    script.write_text(LONG_STAGES)
    run = subprocess.Popen([sys.executable, str(script), str(tmp_path)])
    try:
        deadline = time.time() + 60
        while not all((tmp_path / f"{name}.started").exists() for name in "ab"):
            assert time.time() < deadline and run.poll() is None, "the stages did not start"
            time.sleep(0.1)
        run.send_signal(signal.SIGINT)
        assert run.wait(timeout=60) == 130
    finally:
        run.kill()
    assert all((tmp_path / f"{name}.stopped").exists() for name in "ab")

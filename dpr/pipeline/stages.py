"""Stages of a campaign, stored by what they depend on and run in the order of their needs, in this process, in
worker processes or on a Ray cluster.

A :class:`Stage` is one piece of work (a dataset, a training run, an evaluation) with a ``kind``, the ``settings``
its output depends on, and the stages whose outputs it reads (``needs``). Its :attr:`Stage.key` hashes all of these,
the needed stages' keys included, so two stages with one key make the same output. A :class:`StageStore` keeps each
output under ``<root>/<kind>/<key>/``, and any later run that needs it takes it from there: a resumed run, another
task run into the same folder at the same time, or a candidate recipe that shares the first stages of a record
(``reuse``: other run folders whose stores are read, never written).

Each output folder holds ``stage.json``, written last: the stage's kind, settings, needs and every file's size and
SHA-256. A folder whose files no longer match it (a truncated model, a half-copied dataset) is set aside as
``<key>.corrupt`` and built again, never used; every stored stage a run's targets depend on is checked so, those
that no target needs any more too (a dataset whose clones are stored). A stage builds into ``<key>.partial`` and
is renamed into place once complete, so a run killed at any moment leaves the whole output or none; what survives
a kill inside a stage (a training run's snapshots, a dataset's saved episodes) lives in ``work/<kind>-<key>/``
beside the store and is resumed from. A stage is built by one run at a time (a lock file beside its folder):
another run into the same folder that needs it waits for it, saying so, and takes the output as stored.

Backends (:data:`BACKENDS`): ``local`` runs the stages in this process when ``workers`` is 1, else in ``workers``
processes, each stage submitted once all it needs is done; ``ray`` submits every stage as a Ray task with its needs
as arguments, so Ray orders them. Every stage runs with one torch thread, so its output does not depend on where it
ran.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from dpr.atomic import atomic_write_text, file_sha256
from dpr.checks import ParameterError, check_choice, check_int
from dpr.interrupts import first_completed
from dpr.locks import FolderLock, LockHeld

BACKENDS = ("local", "ray")


@dataclass(frozen=True)
class Backend:
    """Where a campaign's stages run: ``name`` "local" (this machine's processes) or "ray" (a new local cluster, or
    the one at ``address``), ``workers`` stages at once. Checked when a session starts (:func:`backend_session`)."""

    name: str = "local"
    workers: int = 1
    address: str | None = None


MANIFEST = "stage.json"
WORK = "work"  # beside the store: what a stage stopped part-way resumes from

Log = Callable[[str], None]
# A stage's builder: (settings, {role: needed stage's output folder}, output folder, work folder, show_progress).
# A module-level function, so that worker processes and Ray find it by name.
Builder = Callable[[Mapping[str, Any], Mapping[str, Path], Path, Path, bool], None]


@dataclass(eq=False)
class Stage:
    """One piece of work: ``build(settings, inputs, out, work, show_progress)`` writes its output into ``out``, from
    the outputs of ``needs`` (role -> stage) passed as ``inputs`` (role -> folder). ``name`` labels it in the log;
    ``unkeyed`` settings reach the builder without entering the key (a file identified by its hash in
    ``settings``)."""

    kind: str
    name: str
    settings: dict[str, Any]
    build: Builder
    needs: dict[str, Stage] = field(default_factory=dict)
    unkeyed: dict[str, Any] = field(default_factory=dict)

    @cached_property
    def key(self) -> str:
        """The SHA-256 (20 hex digits) of the kind, settings and the needed stages' keys."""
        content = {"kind": self.kind, "settings": self.settings, "needs": {r: s.key for r, s in self.needs.items()}}
        return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:20]

    def record(self) -> dict[str, Any]:
        """What ``stage.json`` says of the stage, before its files."""
        return {
            "kind": self.kind,
            "key": self.key,
            "name": self.name,
            "settings": self.settings,
            "needs": {role: f"{need.kind}/{need.key}" for role, need in self.needs.items()},
        }


def closure(targets: Iterable[Stage]) -> list[Stage]:
    """``targets`` and everything they need, each once, every stage after the stages it needs."""
    ordered: dict[str, Stage] = {}

    def visit(stage: Stage) -> None:
        if stage.key not in ordered:
            for need in stage.needs.values():
                visit(need)
            ordered[stage.key] = stage

    for stage in targets:
        visit(stage)
    return list(ordered.values())


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST)


def write_manifest(stage: Stage, folder: Path, seconds: float) -> None:
    """``stage.json`` in ``folder``: the stage, how long it took, and each file's size and SHA-256."""
    files = {
        p.relative_to(folder).as_posix(): {"bytes": p.stat().st_size, "sha256": file_sha256(p)} for p in _files(folder)
    }
    record = {**stage.record(), "seconds": round(seconds, 1), "files": files}
    atomic_write_text(folder / MANIFEST, json.dumps(record, indent=1, sort_keys=True))


def damage(folder: Path) -> str | None:
    """Why ``folder``'s files do not match its ``stage.json`` (None when they do)."""
    try:
        listed = json.loads((folder / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return f"{MANIFEST} is missing or unreadable"
    present = {p.relative_to(folder).as_posix(): p for p in _files(folder)}
    if set(present) != set(listed):
        return f"its files differ from {MANIFEST}'s list ({sorted(set(present) ^ set(listed))[:3]}...)"
    for name, path in present.items():
        if path.stat().st_size != listed[name]["bytes"] or file_sha256(path) != listed[name]["sha256"]:
            return f"{name} does not match its size and SHA-256 in {MANIFEST}"
    return None


def _set_aside(folder: Path, suffix: str) -> Path:
    """Rename ``folder`` to ``<folder>.<suffix>``, ``.<suffix>-2``... (kept, never deleted)."""
    target, n = folder.with_name(f"{folder.name}.{suffix}"), 1
    while target.exists():
        n += 1
        target = folder.with_name(f"{folder.name}.{suffix}-{n}")
    return folder.replace(target)


class StageStore:
    """The outputs of stages under ``root`` (``<root>/<kind>/<key>/``), and read-only ``reuse`` stores whose outputs
    are copied in when this one lacks them."""

    def __init__(self, root: str | Path, reuse: Sequence[str | Path] = ()):
        self.root = Path(root)
        self.reuse = [Path(r) for r in reuse if Path(r).resolve() != self.root.resolve()]

    def path(self, stage: Stage) -> Path:
        return self.root / stage.kind / stage.key

    @property
    def work(self) -> Path:
        return self.root.parent / WORK

    def find(self, stage: Stage, log: Log) -> str | None:
        """Where ``stage``'s output comes from when it is stored whole: "here", or the reuse store it was copied in
        from (None: it must be built). A damaged output is set aside as ``<key>.corrupt`` and not used."""
        own = self.path(stage)
        if own.is_dir():
            why = damage(own)
            if why is None:
                return "here"
            log(f"dpr pipeline: {stage.name}: {own} is damaged ({why}); set aside as {_set_aside(own, 'corrupt')}")
        for store in self.reuse:
            other = store / stage.kind / stage.key
            if other.is_dir() and damage(other) is None:
                partial = own.with_name(f"{own.name}.partial")
                if partial.exists():
                    shutil.rmtree(partial)
                own.parent.mkdir(parents=True, exist_ok=True)
                shutil.copytree(other, partial)
                partial.replace(own)
                return str(store.parent)
        return None


def build_stage(stage: Stage, root: str, show_progress: bool, *_needs_done: Any) -> tuple[str, float]:
    """Build ``stage`` into the store at ``root`` (in whichever process runs it) and return its name and seconds.
    ``_needs_done`` are the results of the stages it needs, which Ray passes so as to run it after them."""
    import torch

    torch.set_num_threads(1)  # one CPU per stage: the output does not depend on the machine's cores
    store = StageStore(root)
    final = store.path(stage)
    if final.is_dir() and damage(final) is None:  # another run into this folder built it meanwhile
        return stage.name, 0.0
    final.parent.mkdir(parents=True, exist_ok=True)
    lock = _stage_lock(stage, final)
    try:
        if final.is_dir() and damage(final) is None:  # the run it waited for built it
            return stage.name, 0.0
        partial = final.with_name(f"{final.name}.partial")
        if partial.exists():  # left by a run killed while it built: incomplete, rebuilt from the work folder
            shutil.rmtree(partial)
        partial.mkdir()
        work = store.work / f"{stage.kind}-{stage.key}"
        work.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        inputs = {role: store.path(need) for role, need in stage.needs.items()}
        stage.build({**stage.settings, **stage.unkeyed}, inputs, partial, work, show_progress)
        seconds = time.perf_counter() - started
        write_manifest(stage, partial, seconds)
        partial.replace(final)
        shutil.rmtree(work, ignore_errors=True)
    finally:
        lock.release()
    return stage.name, seconds


def _stage_lock(stage: Stage, final: Path) -> FolderLock:
    """The lock of ``stage``'s output ``final``, held: one run builds a stage at a time. Another run into the same
    folder that is building it is waited for, and a line on stderr says so and on what (its output is then taken
    as stored)."""
    lock = FolderLock(final.with_name(f".{final.name}.lock"))
    try:
        lock.acquire()
    except LockHeld as held:
        print(
            f"dpr pipeline: {stage.name}: waiting for another `dpr pipeline`{held.holder}, which is building {final}",
            file=sys.stderr,
            flush=True,
        )
        lock.wait = True
        lock.acquire()
    return lock


def run_stages(
    targets: Sequence[Stage],
    store: StageStore,
    *,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    show_progress: bool = True,
    log: Log = lambda line: print(line, file=sys.stderr),
) -> dict[str, str]:
    """Make every output ``targets`` need and return, per stage key, where it came from: "built", "here" (stored
    already) or a reuse store's run folder. A stage is built only when it is missing and a target needs it, or
    when it is stored damaged: every stored stage of the targets' graph is checked against its ``stage.json``
    first, those that no target needs any more too (a dataset whose clones are stored), so that no damaged input is
    read and none lies in the folder unnoticed; one line is logged per finished stage. ``workers`` stages run at
    once; ``backend`` "ray" joins the cluster at ``address`` (a new local one when None)."""
    with backend_session(backend, workers, address):
        required = {stage.key for stage in targets}  # grows by what each stage to build needs
        origin: dict[str, str] = {}
        needed: list[Stage] = []
        for stage in reversed(closure(targets)):  # dependents first
            if stage.key not in required and not store.path(stage).is_dir():
                continue  # neither stored nor needed: not read by this run
            found = store.find(stage, log)  # every stored stage is checked: it may be read by one this run builds
            if found is None:
                needed.append(stage)
                required.update(need.key for need in stage.needs.values())
            else:
                origin[stage.key] = found
        needed.reverse()
        reused = [where for where in origin.values() if where != "here"]
        log(
            f"dpr pipeline: {len(origin) + len(needed)} stages: {len(origin)} stored"
            + (f" ({len(reused)} reused from {', '.join(sorted(set(reused)))})" if reused else "")
            + f", {len(needed)} to build"
            + (f" by {workers} {backend} workers" if workers > 1 or backend == "ray" else "")
        )
        started = time.perf_counter()

        def finished(index: int, name: str, seconds: float) -> None:
            elapsed = time.perf_counter() - started
            log(f"dpr pipeline: [{index}/{len(needed)}] {name}: done in {seconds:.0f} s ({elapsed:.0f} s elapsed)")

        if not needed:
            return origin
        if backend == "ray":
            _run_on_ray(needed, store, finished)
        elif workers == 1:
            for index, stage in enumerate(needed, 1):
                finished(index, *build_stage(stage, str(store.root), show_progress))
        else:
            _run_in_processes(needed, store, workers, finished)
        return origin | {stage.key: "built" for stage in needed}


def chain_lengths(stages: Sequence[Stage]) -> dict[str, int]:
    """Per stage key: how many of ``stages`` lie on the longest chain from it (itself included) through the stages
    that need it, in turn. A stage with a long chain behind it holds up more of the run, so it goes first."""
    dependents: dict[str, list[Stage]] = {stage.key: [] for stage in stages}
    for stage in stages:
        for need in stage.needs.values():
            if need.key in dependents:
                dependents[need.key].append(stage)
    lengths: dict[str, int] = {}
    for stage in reversed(closure(stages)):  # every stage after those it needs: reversed, dependents come first
        if stage.key in dependents:
            lengths[stage.key] = 1 + max((lengths[d.key] for d in dependents[stage.key]), default=0)
    return lengths


def _run_in_processes(needed: list[Stage], store: StageStore, workers: int, finished: Callable) -> None:
    """Build ``needed`` in ``workers`` processes, each stage once all it needs is built; of the stages ready, the one
    with the longest chain of stages behind it first (:func:`chain_lengths`; the order never changes an output)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    waiting, done, running = list(needed), set(), {}
    building = {stage.key for stage in needed}
    chain = chain_lengths(needed)
    # forked: the workers start with this process's imports (torch, SB3) instead of importing them again; every
    # builder seeds what it draws, so nothing a worker inherits changes an output
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        try:
            while waiting or running:
                ready = [s for s in waiting if all(n.key in done or n.key not in building for n in s.needs.values())]
                ready.sort(key=lambda s: -chain[s.key])  # stable: equal chains keep the order of their needs
                for stage in ready[: workers - len(running)]:  # a free worker takes the ready stage first in line
                    waiting.remove(stage)
                    running[pool.submit(build_stage, stage, str(store.root), False)] = stage
                for future in first_completed(running):
                    stage = running.pop(future)
                    finished(len(done) + 1, *future.result())
                    done.add(stage.key)
        except BaseException as error:
            pool.shutdown(wait=False, cancel_futures=True)
            if isinstance(error, KeyboardInterrupt):
                _interrupt_workers(running)
            raise


STOP_GRACE_S = 5.0  # how long an interrupted run waits for its workers to stop by themselves


def _interrupt_workers(running: Mapping) -> None:
    """After a Ctrl-C: the workers' stages stop at their next safe point and keep what they did. A Ctrl-C at a
    terminal reaches the workers too; a SIGINT sent to this process alone (``kill -INT``, a job manager) does not,
    and the run would wait for every stage in flight to end, which can take an hour. So the workers still busy
    after STOP_GRACE_S get the SIGINT passed on."""
    import multiprocessing
    import signal
    from concurrent.futures import wait

    _, busy = wait(running, timeout=STOP_GRACE_S)
    if busy:
        for worker in multiprocessing.active_children():
            with contextlib.suppress(ProcessLookupError):
                os.kill(worker.pid, signal.SIGINT)


def _run_on_ray(needed: list[Stage], store: StageStore, finished: Callable) -> None:
    """Submit every stage of ``needed`` as a Ray task taking the tasks of the stages it needs as arguments, so that
    Ray runs it after them; one CPU each."""
    import ray

    remote = ray.remote(num_cpus=1, max_retries=0)(build_stage)
    refs: dict[str, Any] = {}
    for stage in needed:
        upstream = [refs[need.key] for need in stage.needs.values() if need.key in refs]
        refs[stage.key] = remote.remote(stage, str(store.root.resolve()), False, *upstream)
    pending, count = list(refs.values()), 0
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            count += 1
            finished(count, *ray.get(ready[0]))
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise


@contextlib.contextmanager
def backend_session(backend: str, workers: int, address: str | None) -> Iterator[None]:
    """Check the backend settings, and for backend "ray" join (or start) the Ray cluster, left again at the end if
    this session started the connection: a ParameterError names a bad setting before any work."""
    check_choice("backend", backend, BACKENDS)
    check_int("workers", workers, 1)
    if address is not None and backend != "ray":
        raise ParameterError("address", "joins a Ray cluster; it needs backend 'ray'")
    connected = backend == "ray" and connect_ray(address, workers)
    try:
        yield
    finally:
        if connected:
            import ray

            ray.shutdown()


def connect_ray(address: str | None, workers: int) -> bool:
    """Join the Ray cluster at ``address`` (``host:port``), or start a local one of ``workers`` CPUs; False when
    this process is connected already. An address where nothing answers is a ParameterError naming it."""
    try:
        import ray
    except ImportError:
        raise ParameterError(
            "backend", "'ray' needs Ray: pip install -e '.[distributed]' (or pip install 'ray>=2.50,<3')"
        ) from None
    if ray.is_initialized():
        return False
    if address is not None and address != "auto":
        host, _, port = address.rpartition(":")
        try:
            socket.create_connection((host or "127.0.0.1", int(port)), timeout=3).close()
        except (OSError, ValueError):
            raise ParameterError("address", f"no Ray cluster answers at {address!r} (expected host:port)") from None
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    if address is None:
        ray.init(num_cpus=workers, include_dashboard=False, configure_logging=False, log_to_driver=True)
    else:
        ray.init(address=address, configure_logging=False, log_to_driver=True)
    return True

"""Environment throughput: env steps per second against the physics-only rate of the same world.

For each robot model and swarm size, one run steps ``gymnasium.make("dpr/Navigation-v0", ...)`` with
uniformly random actions and times, in the same run:

* ``env``: whole ``env.step`` calls (wrappers, command rule, magnets, observation, reward, info);
* ``physics``: the pymunk part of those same steps (``World.step_physics``: ``space.step`` called
  ``substeps`` times per env step on the same space), timed inside the env steps, so both figures come
  from the same trajectory;
* ``physics_replay``: ``step_physics`` called again on the same space after the run, with no commands in
  between (a quieter state: paddles rest against their stops, so it runs faster than under commands).

``env / physics`` is the fraction of an env step spent in pymunk; ``1 - env / physics`` is Python overhead.
Each figure is the median over ``repeats`` blocks; the blocks of all configurations are interleaved.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

# The 2021 implementation on this machine's kind, env steps/s (paddle model, random actions).
REFERENCE_2021 = {9: 130.0, 25: 41.0, 49: 18.6, 100: 7.3}


class _Bench:
    """One configuration's env, its random actions, and the timing hooks (see the module docstring)."""

    def __init__(self, robot_model: str, n_robots: int, steps: int, seed: int = 0):
        import dpr  # noqa: F401  (registers the ids)

        self.robot_model, self.n_robots, self.steps = robot_model, n_robots, steps
        self.env = gym.make("dpr/Navigation-v0", n_robots=n_robots, robot_model=robot_model)
        self.env.reset(seed=seed)
        self.env.action_space.seed(seed)
        self.physics_time = 0.0
        self._time_the_physics()
        self.env_rates, self.physics_rates, self.replay_rates = [], [], []
        started = time.perf_counter()
        self._steps(self._actions())  # warm-up
        self.warm_up_rate = steps / (time.perf_counter() - started)

    @classmethod
    def sized(cls, robot_model: str, n_robots: int, seconds: float, seed: int = 0) -> _Bench:
        """A bench whose blocks take about ``seconds`` each (at least 20 steps), sized by a 20-step warm-up."""
        bench = cls(robot_model, n_robots, 20, seed)
        bench.steps = max(20, round(bench.warm_up_rate * seconds))
        return bench

    def _time_the_physics(self) -> None:
        """Hook the timer into the env's world (a reset builds a new one)."""
        self.world = self.env.unwrapped.world
        self.plain_step_physics = self.world.step_physics
        self.world.step_physics = self._timed_step_physics

    def _actions(self) -> list:
        return [self.env.action_space.sample() for _ in range(self.steps)]

    def _steps(self, actions: list) -> None:
        for action in actions:
            _, _, terminated, truncated, _ = self.env.step(action)
            if terminated or truncated:  # as a learner would: part of what an env step costs
                self.env.reset()
                self._time_the_physics()

    def _timed_step_physics(self) -> None:
        t0 = time.perf_counter()
        self.plain_step_physics()
        self.physics_time += time.perf_counter() - t0

    def block(self) -> None:
        """One timed block: env steps, the physics inside them, then physics-only replay. Its actions are drawn
        before the clock starts."""
        actions = self._actions()
        self.physics_time = 0.0
        t0 = time.perf_counter()
        self._steps(actions)
        self.env_rates.append(self.steps / (time.perf_counter() - t0))
        self.physics_rates.append(self.steps / self.physics_time)
        t0 = time.perf_counter()
        for _ in range(self.steps):
            self.plain_step_physics()
        self.replay_rates.append(self.steps / (time.perf_counter() - t0))

    def row(self) -> dict:
        env_rate, physics_rate = float(np.median(self.env_rates)), float(np.median(self.physics_rates))
        return {
            "robot_model": self.robot_model,
            "n_robots": self.n_robots,
            "substeps": self.world.swarm.substeps,
            "env_steps_per_s": env_rate,
            "physics_steps_per_s": physics_rate,
            "physics_replay_steps_per_s": float(np.median(self.replay_rates)),
            "env_over_physics": env_rate / physics_rate,
            "us_per_robot_step": 1e6 / env_rate / self.n_robots,
        }


def bench_env(robot_model: str, n_robots: int, steps: int = 200, repeats: int = 5, seed: int = 0) -> dict:
    """One configuration on its own."""
    bench = _Bench(robot_model, n_robots, steps, seed)
    for _ in range(repeats):
        bench.block()
    bench.env.close()
    return bench.row()


def run_benchmarks(
    models=("paddle", "disk"), sizes=(9, 25, 49, 100), steps: int = 200, repeats: int = 5, progress=None
):
    """Every configuration, with their timed blocks interleaved (repeat r of every configuration, then repeat
    r + 1, ...), so that a change in the machine's load hits all configurations alike and ratios between
    them (disk / paddle) are fair. Blocks are sized to take about the same time."""
    benches = []
    for model in models:
        for n in sizes:
            # fewer steps for the slow big paddle swarms keep the whole run to a few minutes
            k = max(20, int(steps * 9 / n)) if model == "paddle" else steps * 5
            benches.append(_Bench(model, n, k))
    for _ in range(repeats):
        for bench in benches:
            bench.block()
    rows = []
    for bench in benches:
        bench.env.close()
        rows.append(bench.row())
        if progress is not None:
            progress(rows[-1])
    return rows


def format_table(rows: list[dict]) -> str:
    lines = [
        "| model | N | substeps | env steps/s | physics-only steps/s | env / physics | replay physics steps/s "
        "| µs per robot-step | 2021 env steps/s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        ref = REFERENCE_2021.get(r["n_robots"]) if r["robot_model"] == "paddle" else None
        lines.append(
            f"| {r['robot_model']} | {r['n_robots']} | {r['substeps']} | {r['env_steps_per_s']:.0f} | "
            f"{r['physics_steps_per_s']:.0f} | {r['env_over_physics']:.0%} | {r['physics_replay_steps_per_s']:.0f} | "
            f"{r['us_per_robot_step']:.1f} | {ref if ref is not None else '-'} |"
        )
    by = {(r["robot_model"], r["n_robots"]): r for r in rows}
    if ("paddle", 9) in by and ("disk", 9) in by:
        ratio = by[("disk", 9)]["env_steps_per_s"] / by[("paddle", 9)]["env_steps_per_s"]
        lines.append("")
        lines.append(f"disk / paddle env steps/s at N=9: {ratio:.1f}x")
    for model in ("paddle", "disk"):
        sizes = sorted(n for m, n in by if m == model)
        if len(sizes) > 1:
            first, last = by[(model, sizes[0])], by[(model, sizes[-1])]
            growth = last["us_per_robot_step"] / first["us_per_robot_step"]
            lines.append(f"{model}: cost per robot-step at N={sizes[-1]} is {growth:.2f}x that at N={sizes[0]}")
    return "\n".join(lines)


# -- the batched engine ------------------------------------------------------------------------------------------
BATCHED_ENVS = (1, 64, 1024, 4096, 16384)  # K at N=9
BATCHED_SIZES = (100, 1000, 10000)  # N, with K*N near BATCHED_ROBOTS robots in all
BATCHED_ROBOTS = 10_000
PYMUNK_LARGEST = 1000  # the largest N timed on the pymunk disk env beside the batched rows


class _BatchedBench:
    """``num_envs`` Navigation envs of N robots on the batched engine, stepped through ``step_tensors`` (physics,
    observation, reward, same-step resets) with random actions drawn on the device, after one warm-up step (with
    ``compile``, the compiling)."""

    def __init__(self, num_envs: int, n_robots: int, device: str = "cpu", seed: int = 0, compile: bool = False):
        import torch

        self.envs = gym.make_vec(
            "dpr/Navigation-v0",
            num_envs=num_envs,
            vectorization_mode="vector_entry_point",
            robot_model="disk",
            n_robots=n_robots,
            device=device,
            compile=compile,
        ).unwrapped
        if self.envs.device.type == "cuda":  # this row's peak, not an earlier row's
            torch.cuda.reset_peak_memory_stats(self.envs.device)
        self.envs.reset_tensors(seed)
        self.generator = torch.Generator(device=self.envs.device).manual_seed(seed)
        self.num_envs, self.n_robots, self.rates = num_envs, n_robots, []
        self._step()

    def _step(self) -> None:
        import torch

        shape, device = (self.num_envs, self.n_robots), self.envs.device
        self.envs.step_tensors(torch.randint(0, 2, shape, generator=self.generator, device=device))

    def block(self, seconds: float) -> None:
        """One timed block of at least two steps and ``seconds``."""
        import torch

        if self.envs.device.type == "cuda":  # nothing queued before the clock starts
            torch.cuda.synchronize(self.envs.device)
        count, started = 0, time.perf_counter()
        while count < 2 or time.perf_counter() - started < seconds:
            self._step()
            count += 1
        if self.envs.device.type == "cuda":
            torch.cuda.synchronize(self.envs.device)
        self.rates.append(count * self.num_envs / (time.perf_counter() - started))

    def close(self) -> dict:
        """The row: the median block's env steps/s, and the peak memory of the device while this bench ran (CUDA), or
        of the process so far."""
        import resource

        import torch

        envs = self.envs
        if envs.device.type == "cuda":
            peak = torch.cuda.max_memory_allocated(envs.device)
        else:
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # the process's, in bytes (Linux: KiB)
        envs.close()
        rate = float(np.median(self.rates))
        return {
            "engine": "batched",
            "device": str(envs.device),
            "compiled": envs.world.compiled,
            "num_envs": self.num_envs,
            "n_robots": self.n_robots,
            "env_steps_per_s": rate,
            "us_per_robot_step": 1e6 / (rate * self.n_robots),
            "peak_memory_mb": peak / 2**20,
        }


def bench_batched(
    num_envs: int, n_robots: int, seconds: float = 2.0, device: str = "cpu", seed: int = 0, compile: bool = False
) -> dict:
    """Env steps per second of ``num_envs`` Navigation envs of N robots on the batched engine, timed for at least
    ``seconds`` (:class:`_BatchedBench`), and its peak memory."""
    bench = _BatchedBench(num_envs, n_robots, device, seed, compile)
    bench.block(seconds)
    return bench.close()


def batched_cases(ks, sizes, robots: int = BATCHED_ROBOTS, device="cpu") -> list[tuple[int, int]]:
    """The (K, N) of every row of :func:`run_batched_benchmarks`: N=9 at each K in ``ks``, then each N in ``sizes`` at
    K*N near ``robots``; a ParameterError (naming ``device`` or ``num_envs``) for a row this machine cannot hold."""
    from dpr.sim.batched import checked_size

    cases = [(k, 9) for k in ks] + [(max(1, robots // n), n) for n in sizes]
    for k, n in cases:
        checked_size(k, n, device)
    return cases


def run_batched_benchmarks(
    ks=BATCHED_ENVS,
    sizes=BATCHED_SIZES,
    seconds: float = 1.0,
    repeats: int = 3,
    device="cpu",
    progress=None,
    compile: bool = False,
    robots: int = BATCHED_ROBOTS,
):
    """The batched engine at N=9 for every K in ``ks`` and at every N in ``sizes`` (K*N near ``robots``), each
    beside the pymunk disk env at the same N (random actions, resets at episode ends; not above
    ``PYMUNK_LARGEST``, whose steps take seconds), in one run.

    Each row is timed in ``repeats`` blocks of at least ``seconds``, each right after a block of the pymunk env of
    about the same length, with one more pymunk block after the last: both sides of a row's ratio see the same
    machine, and its figures are the medians of its own blocks."""
    cases = batched_cases(ks, sizes, robots, device)
    pymunk = {n: _Bench.sized("disk", n, seconds) for n in sorted({n for _, n in cases}) if n <= PYMUNK_LARGEST}
    rows = []
    for k, n in cases:
        reference, batched = pymunk.get(n), _BatchedBench(k, n, device, compile=compile)
        first = len(reference.env_rates) if reference else 0
        for _ in range(repeats):
            if reference:
                reference.block()
            batched.block(seconds)
        if reference:
            reference.block()
        row = batched.close()
        row["pymunk_env_steps_per_s"] = float(np.median(reference.env_rates[first:])) if reference else None
        rows.append(row)
        if progress is not None:
            progress(row)
    for reference in pymunk.values():
        reference.env.close()
    return rows


def format_batched_table(rows: list[dict]) -> str:
    lines = [
        "| N | K | pymunk env steps/s | batched env steps/s | batched / pymunk (robot-steps) | µs per robot-step "
        "| peak memory (MiB) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        reference = r["pymunk_env_steps_per_s"]
        ratio = f"{r['env_steps_per_s'] / reference:.1f}x" if reference else "-"
        lines.append(
            f"| {r['n_robots']} | {r['num_envs']} | {f'{reference:.0f}' if reference else '-'} | "
            f"{r['env_steps_per_s']:.0f} | {ratio} | {r['us_per_robot_step']:.2f} | {r['peak_memory_mb']:.0f} |"
        )
    return "\n".join(lines)

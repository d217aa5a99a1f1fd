"""The batched disk engine (dpr.sim.batched): shapes, the command rule, growth, neighbours, determinism, errors, and
agreement with the pymunk disk model on a short wave."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from dpr.checks import ParameterError
from dpr.sim import constants as C
from dpr.sim.batched import BatchedDiskWorld
from dpr.sim.batched.neighbours import all_pairs, cell_pairs
from dpr.sim.objects import gate_polygons
from dpr.sim.swarm import REACHED_FRACTION
from dpr.sim.world import World, grid_centres


def _world(k=2, n=9, spread=(0.0, 0.0), **kwargs) -> BatchedDiskWorld:
    world = BatchedDiskWorld(k, n, **kwargs)
    centres = torch.tensor(np.stack([grid_centres(n, (500.0 + i * spread[0], i * spread[1])) for i in range(k)]))
    world.reset(torch.ones(k, dtype=torch.bool), centres, torch.zeros(k, n, dtype=torch.bool))
    return world


def test_shapes_and_dtypes():
    world = BatchedDiskWorld(3, 5, n_walls=2, object_radius=30.0)
    for name, shape in [
        ("position", (3, 5, 2)),
        ("velocity", (3, 5, 2)),
        ("angular_velocity", (3, 5)),
        ("radius", (3, 5)),
        ("expansion", (3, 5)),
        ("target", (3, 5)),
        ("object_position", (3, 2)),
        ("object_velocity", (3, 2)),
        ("walls", (3, 2, 4, 2)),
    ]:
        assert tuple(getattr(world, name).shape) == shape and getattr(world, name).dtype == torch.float32, name
    assert world.moving.dtype == torch.bool and world.alive.dtype == torch.bool
    world.step(torch.ones(3, 5))
    assert world.is_sane().shape == (3,) and world.max_overlap().shape == (3,)
    assert world.robots_touch_walls().dtype == torch.bool


def test_masked_reset_touches_only_masked_swarms():
    world = _world(k=3)
    for _ in range(5):
        world.step(torch.ones(3, 9))
    before = world.position.clone(), world.radius.clone()
    fresh = torch.tensor(np.stack([grid_centres(9, (0.0, 900.0))] * 3))
    dead = torch.zeros(3, 9, dtype=torch.bool)
    dead[1, 0] = True
    world.reset(torch.tensor([False, True, False]), fresh, dead)
    assert torch.equal(world.position[1], fresh[1].float())
    assert torch.all(world.radius[1] == np.float32(C.DISK_CONTRACTED_RADIUS)) and torch.all(world.expansion[1] == 0)
    assert not world.alive[1, 0] and world.alive[0].all() and world.alive[2].all()
    for swarm in (0, 2):
        assert torch.equal(world.position[swarm], before[0][swarm])
        assert torch.equal(world.radius[swarm], before[1][swarm])


def test_state_stays_laid_out_body_major_through_resets_and_steps():
    # The inputs come swarm-major ([K, ...]); a transposed view kept as state would be read across its rows in
    # every substep.
    world = BatchedDiskWorld(4, 5, n_walls=2, object_radius=30.0)
    centres = torch.tensor(np.stack([grid_centres(5, (0.0, 300.0 * i)) for i in range(4)]))
    world.reset(
        torch.ones(4, dtype=torch.bool),
        centres,
        torch.zeros(4, 5, dtype=torch.bool),
        object_position=torch.zeros(4, 2),
        dynamics=torch.ones(4, 3),
    )
    for _ in range(2):
        world.step(torch.ones(4, 5))
    state = world.state_dict()
    assert state and all(value.is_contiguous() for value in state.values()), [
        name for name, value in state.items() if not value.is_contiguous()
    ]


def test_command_rule_keeps_a_moving_robot_on_its_target():
    """Swarm.command: a robot accepts a new target only once it has reached its previous one."""
    world = _world(k=1, n=1)
    world.step(torch.ones(1, 1))  # expand: a stroke takes ~3 steps
    assert world.moving[0, 0] and world.target[0, 0] == 1
    world.step(torch.zeros(1, 1))  # ignored: still moving
    assert world.target[0, 0] == 1
    for _ in range(3):
        world.step(torch.ones(1, 1))
    assert world.expansion[0, 0] == pytest.approx(1.0, abs=1e-5)
    world.step(torch.zeros(1, 1))  # reached: accepted
    assert world.target[0, 0] == 0
    assert (1 - world.expansion[0, 0]) < 1 - REACHED_FRACTION


def test_dead_robots_stay_contracted_and_keep_magnets():
    world = BatchedDiskWorld(1, 9)
    dead = torch.zeros(1, 9, dtype=torch.bool)
    dead[0, 4] = True
    world.reset(torch.ones(1, dtype=torch.bool), torch.tensor(grid_centres(9, (0, 0)))[None], dead)
    for step in range(20):
        world.step(torch.full((1, 9), float(step % 8 < 4)))
        assert world.radius[0, 4] == np.float32(C.DISK_CONTRACTED_RADIUS) and world.target[0, 4] == 0
    gaps = (world.position[0] - world.position[0, 4]).norm(dim=1)
    assert (gaps[[1, 3, 5, 7]] < C.DISK_MAGNET_RANGE).all()  # its rods hold it among its neighbours


def test_growth_into_a_neighbour_is_limited():
    """Two touching robots: one expanding presses at most DISK_GROWTH_OVERLAP per step into the other."""
    world = BatchedDiskWorld(1, 2)
    gap = 2 * C.DISK_CONTRACTED_RADIUS
    world.reset(
        torch.ones(1, dtype=torch.bool), torch.tensor([[[0.0, 0.0], [gap, 0.0]]]), torch.zeros(1, 2, dtype=bool)
    )
    free = BatchedDiskWorld(1, 1)
    free.reset(torch.ones(1, dtype=torch.bool), torch.zeros(1, 1, 2), torch.zeros(1, 1, dtype=bool))
    world.step(torch.tensor([[1.0, 0.0]]))
    free.step(torch.ones(1, 1))
    grown = world.radius[0, 0] - C.DISK_CONTRACTED_RADIUS
    assert grown <= C.DISK_GROWTH_OVERLAP + 1e-5 < free.radius[0, 0] - C.DISK_CONTRACTED_RADIUS
    assert world.expansion[0, 0] < free.expansion[0, 0]


@pytest.mark.parametrize("n, ball", [(9, True), (40, False)])  # all pairs with the ball; the cell list
def test_deterministic(n, ball):
    runs = []
    for _ in range(2):
        world = _world(k=2, n=n, spread=(37.0, 11.0), object_radius=40.0 if ball else None)
        for step in range(15):
            world.step((torch.arange(n) % 3 == step % 3).float().expand(2, n))
        runs.append(world.position.clone())
    assert torch.equal(runs[0], runs[1])


@pytest.mark.parametrize(
    "kwargs, parameter",
    [
        ({"num_envs": 0, "n_robots": 9}, "num_envs"),
        ({"num_envs": 1, "n_robots": 0}, "n_robots"),
        ({"num_envs": 1, "n_robots": 9, "device": "cuda"}, "device"),
        ({"num_envs": 10**9, "n_robots": 10**4}, "num_envs"),
    ],
)
def test_bad_input_names_the_argument(kwargs, parameter):
    if parameter == "device" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(ParameterError) as error:
        BatchedDiskWorld(**kwargs)
    assert error.value.parameter == parameter


def test_a_world_builds_where_the_platform_does_not_say_its_memory(monkeypatch):
    """Windows has no os.sysconf: the memory check then assumes plenty (dpr.limits.physical_memory), as the pymunk
    envs' does, rather than stopping on an AttributeError."""
    monkeypatch.delattr(os, "sysconf")
    assert BatchedDiskWorld(num_envs=2, n_robots=9).position.shape == (2, 9, 2)


def test_a_cuda_device_this_machine_lacks_is_refused_by_name(monkeypatch):
    """'cuda:3' on a machine of one GPU: a ParameterError naming --device, before torch's bare assertion."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(ParameterError, match=r"sees 1 CUDA device\(s\): cuda:0 to cuda:0") as error:
        BatchedDiskWorld(num_envs=1, n_robots=9, device="cuda:3")
    assert error.value.parameter == "device"


def test_cell_pairs_are_the_all_pairs_neighbours_each_once():
    generator = torch.Generator().manual_seed(0)
    position = torch.rand(3, 300, 2, generator=generator) * 1500 - 700  # dense and sparse corners
    position[1, :40] = torch.rand(40, 2, generator=generator) * 30  # 40 robots in one cell: no cap drops any
    env, first, second = cell_pairs(position, 100.0)
    assert bool((first < second).all())
    found = torch.zeros(3, 300, 300, dtype=torch.bool)
    found[env, first, second] = True
    assert len(env) == int(found.sum())  # none twice
    _, every_valid = all_pairs(position, 100.0)
    assert torch.equal(found, every_valid & torch.ones(300, 300, dtype=torch.bool).triu(1))


def test_cell_list_engine_matches_all_pairs_engine(monkeypatch):
    """The same swarm stepped with the cell list (its limit lowered below N) and with all pairs: same physics."""
    import dpr.sim.batched.world as world_module

    monkeypatch.setattr(world_module, "ALL_PAIRS_LIMIT", 64)
    a = _world(k=2, n=40, spread=(37.0, 11.0))
    monkeypatch.setattr(world_module, "ALL_PAIRS_LIMIT", 8)
    b = _world(k=2, n=40, spread=(37.0, 11.0))
    assert b.use_cells and not a.use_cells
    for step in range(10):
        targets = (torch.arange(40) % 2 == step % 2).float().expand(2, 40)
        a.step(targets)
        b.step(targets)
    assert torch.allclose(a.position, b.position, atol=1e-2)
    assert torch.allclose(a.max_overlap(), b.max_overlap(), atol=1e-3)


@pytest.mark.parametrize("mode", ["gather", "slices"])
def test_every_pair_mode_reads_and_sums_pairs_as_the_matrix_products_do(mode):
    """Compiled substeps read pairs by index (CPU) or read and sum them through slices (GPU), eager ones through
    matrix products: the same values, the body sums in the same order."""
    from dpr.sim.batched.pairs import DensePairs

    generator = torch.Generator().manual_seed(0)
    bodies = [torch.randn(6, 4, generator=generator) for _ in range(2)]
    on_pairs = [torch.randn(15, 4, generator=generator) for _ in range(2)]
    matrix, other = DensePairs(6, 4, torch.device("cpu")), DensePairs(6, 4, torch.device("cpu"), mode)
    for method, values in (
        ("difference", bodies),
        ("total", bodies),
        ("scatter", on_pairs),
        ("scatter_total", on_pairs),
    ):
        for mine, theirs in zip(getattr(other, method)(*values), getattr(matrix, method)(*values)):
            torch.testing.assert_close(mine, theirs, rtol=0, atol=1e-6, msg=method)
    with pytest.raises(ValueError, match="mode"):
        DensePairs(6, 4, torch.device("cpu"), "sparse")


def test_compiled_substeps_follow_the_eager_ones():
    """SolverSettings(compile=True) fuses each substep (on a CPU, pairs read by index and summed through the same
    matrix products) and the command rule with the growth: the same trajectory."""
    from dpr.sim.batched import SolverSettings

    few = {"iterations": 2, "substeps": 1}  # a small graph: compiled in seconds, the same code as the default rounds
    eager = _world(k=3, n=5, solver=SolverSettings(**few))
    compiled = _world(k=3, n=5, solver=SolverSettings(compile=True, **few))
    for step in range(12):
        targets = (torch.arange(5) % 2 == step // 4 % 2).float().expand(3, 5)
        eager.step(targets)
        compiled.step(targets)
    assert torch.allclose(eager.position, compiled.position, atol=1e-3)


def test_walls_block_and_ball_moves():
    walls = np.stack(gate_polygons((0.0, 0.0), (300.0, 0.0), 150.0, at=40.0))
    world = BatchedDiskWorld(1, 1, n_walls=2, object_radius=30.0)
    world.reset(
        torch.ones(1, dtype=torch.bool),
        torch.tensor([[[40.0 - C.DISK_CONTRACTED_RADIUS - 20.0, 120.0]]]),  # 20 units before the upper wall's near face
        torch.zeros(1, 1, dtype=bool),
        walls=torch.tensor(walls)[None],
        object_position=torch.tensor([[-1000.0, 0.0]]),
    )
    assert not world.robots_touch_walls()[0]
    world.bodies.vx[0] = 200.0  # thrown at the wall
    for _ in range(5):
        world.step(torch.zeros(1, 1))
    assert world.robots_touch_walls()[0] or world.position[0, 0, 0] < 40.0 - C.DISK_CONTRACTED_RADIUS + 1.0
    assert world.position[0, 0, 0] < 40.0 - C.DISK_CONTRACTED_RADIUS + 3.0  # not through the wall
    assert torch.equal(world.object_position, torch.tensor([[-1000.0, 0.0]]))


def test_short_wave_agrees_with_pymunk():
    """Smoke test of tools/batched_agreement.py's comparison: a 200-step wave from the same start moves both
    engines' swarms the same way (the full comparison runs 2500 steps over 100 seeds)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent.parent / "tools"))
    from batched_agreement import BatchedWave

    n, steps = 9, 200
    start = np.array([500.0, 0.0])
    world = World(n, "disk", centre=start)
    ours = BatchedDiskWorld(1, n)
    ours.reset(torch.ones(1, dtype=torch.bool), torch.tensor(world.swarm.position)[None], torch.zeros(1, n, dtype=bool))
    goal = torch.zeros(1, 2)
    wave_a, wave_b = BatchedWave(goal, n), BatchedWave(goal, n)
    for _ in range(steps):
        world.step(wave_a(torch.tensor(world.swarm.position, dtype=torch.float32)[None])[0].numpy())
        ours.step(wave_b(ours.position))
    theirs = start[0] - world.centre_of_mass[0]
    mine = start[0] - ours.position[0].mean(dim=0)[0].item()
    assert theirs > 0 and mine > 0
    assert 0.5 < mine / theirs < 2.0


def test_agreement_batched_cache_resumes_in_chunks(tmp_path, monkeypatch):
    """tools/batched_agreement.py steps only the seeds its batched cache lacks, ``chunk`` at a time, appends each
    chunk to the cache as it ends, and returns every key's episode in order; the engine's fingerprint changes with
    the solver settings."""
    import json
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent.parent / "tools"))
    import batched_agreement

    calls = []

    def fake_episodes(starts, **kwargs):
        calls.append([s["seed"] for s in starts])
        seeds = [s["seed"] for s in starts]
        return {
            "displacement": [float(seed) for seed in seeds],
            "overlap": [0.5] * len(seeds),
            "sane": [True] * len(seeds),
        }

    monkeypatch.setattr(batched_agreement, "batched_episodes", fake_episodes)
    cache_path = tmp_path / "batched.jsonl"
    keys = [f"k{seed}" for seed in range(5)]
    cache = {"k1": {"key": "k1", "displacement": 10.0, "overlap": 0.1, "sane": True}}
    result = batched_agreement.cached_batched_episodes(
        [{"seed": seed} for seed in range(5)], keys, cache, cache_path, chunk=2, steps=10, overlap_every=1
    )
    assert calls == [[0, 2], [3, 4]]
    assert result["displacement"] == [0.0, 10.0, 2.0, 3.0, 4.0]
    assert [json.loads(line)["key"] for line in cache_path.read_text().splitlines()] == ["k0", "k2", "k3", "k4"]
    again = batched_agreement.cached_batched_episodes(
        [{"seed": seed} for seed in range(5)], keys, batched_agreement._load_cache(cache_path) | cache, cache_path, 2
    )
    assert calls == [[0, 2], [3, 4]] and again == result
    assert batched_agreement.engine_fingerprint({}) != batched_agreement.engine_fingerprint({"iterations": 20})

"""FrameDataset / EpisodeBlockSampler: exact items (stacking at episode starts), episode selection, the LRU cache
bound, metadata-only construction, stats, sampler order guarantees, DataLoader with workers, bad input, and
ConcatFrames (several datasets as one)."""

import pickle
from collections import Counter

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from dpr.datasets.frames import ConcatFrames, EpisodeBlockSampler, FrameDataset, FrameKeys
from dpr.datasets.lerobot import DatasetError, LeRobotReader, LeRobotWriter

LENGTHS = (5, 3, 7, 1, 4)  # a length-1 episode: its whole stack is its first frame
D, N = 3, 2
H, W = 4, 5


def expected_obs(episode: int, frame: int) -> np.ndarray:
    """The synthetic observation of (episode, frame): every value names its frame."""
    return np.array([episode, frame, 1000 * episode + frame + 0.5], dtype=np.float32)


def expected_action(episode: int, frame: int) -> np.ndarray:
    return np.array([episode + 0.25, frame - 0.75], dtype=np.float32)


def expected_image(episode: int, frame: int) -> np.ndarray:
    image = np.full((H, W, 3), 10 * episode + frame, dtype=np.uint8)
    image[0, 0, 0] = 200  # not constant over the image, so a transposed or flipped read would show
    return image


def write_dataset(root, lengths=LENGTHS, *, image=False, discrete=False):
    features = {
        "observation.state": {"dtype": "float32", "shape": [D], "names": None},
        "action": {"dtype": "int64", "shape": [1], "names": None}
        if discrete
        else {"dtype": "float32", "shape": [N], "names": None},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "next.done": {"dtype": "bool", "shape": [1], "names": None},
        "next.success": {"dtype": "bool", "shape": [1], "names": None},
    }
    if image:
        features["observation.image"] = {"dtype": "image", "shape": [H, W, 3], "names": None}
    writer = LeRobotWriter.create(root, fps=10, features=features, robot_type="paddle")
    for episode, length in enumerate(lengths):
        for frame in range(length):
            values = {
                "observation.state": expected_obs(episode, frame),
                "action": np.array([10 * episode + frame], dtype=np.int64)
                if discrete
                else expected_action(episode, frame),
                "next.reward": np.array([0.1 * frame], dtype=np.float32),
                "next.done": np.array([frame == length - 1]),
                "next.success": np.array([False]),
            }
            if image:
                values["observation.image"] = expected_image(episode, frame)
            writer.add_frame(values, task="navigate")
        writer.save_episode()
    writer.finalize()
    return root


def stacked_obs(episode: int, frame: int, stack: int) -> np.ndarray:
    return np.concatenate([expected_obs(episode, max(frame - k, 0)) for k in range(stack - 1, -1, -1)])


def all_frames(lengths, episodes=None):
    episodes = range(len(lengths)) if episodes is None else episodes
    return [(e, f) for e in episodes for f in range(lengths[e])]


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("frames") / "ds")


@pytest.fixture(scope="module")
def many_root(tmp_path_factory):
    """13 episodes of 2..14 frames, for sampler and DataLoader tests."""
    return write_dataset(tmp_path_factory.mktemp("frames_many") / "ds", lengths=tuple(range(2, 15)))


@pytest.fixture
def count_reads(monkeypatch):
    """Counts LeRobotReader.episode calls (episode indices in call order)."""
    calls: list[int] = []
    original = LeRobotReader.episode

    def counting(self, index, columns=None):
        calls.append(int(index))
        return original(self, index, columns)

    monkeypatch.setattr(LeRobotReader, "episode", counting)
    return calls


def check_item(item, episode, frame, stack=1):
    assert set(item) == {"observation", "action", "frame_index", "episode_index"}
    assert item["observation"].dtype == torch.float32 and item["observation"].shape == (stack * D,)
    np.testing.assert_array_equal(item["observation"].numpy(), stacked_obs(episode, frame, stack))
    np.testing.assert_array_equal(item["action"].numpy(), expected_action(episode, frame))
    assert item["frame_index"].dtype == torch.int64 and int(item["frame_index"]) == frame
    assert item["episode_index"].dtype == torch.int64 and int(item["episode_index"]) == episode


# ------------------------------------------------------------------------------------------------ items


def test_every_item_is_its_frame(root):
    ds = FrameDataset(root)
    frames = all_frames(LENGTHS)
    assert len(ds) == sum(LENGTHS) == len(frames)
    assert (ds.observation_dim, ds.action_dim) == (D, N)
    for i, (episode, frame) in enumerate(frames):
        check_item(ds[i], episode, frame)
        assert ds.locate(i) == (episode, frame)
    check_item(ds[-1], len(LENGTHS) - 1, LENGTHS[-1] - 1)
    assert ds.episode_ranges == [(0, 5), (5, 8), (8, 15), (15, 16), (16, 20)]


@pytest.mark.parametrize("stack", [2, 3, 6])
def test_frame_stack_repeats_the_episode_start_never_the_previous_episode(root, stack):
    ds = FrameDataset(root, frame_stack=stack)
    assert ds.observation_dim == stack * D
    for i, (episode, frame) in enumerate(all_frames(LENGTHS)):
        check_item(ds[i], episode, frame, stack)
    # First frame of episode 1 (item 5): the stack is episode 1's frame 0 only, not episode 0's last frames.
    first = ds[5]["observation"].reshape(stack, D).numpy()
    assert (first[:, 0] == 1).all() and (first[:, 1] == 0).all()
    # Frame 2 of episode 2 (item 10), oldest first: frames max(2 - stack + 1, 0) .. 2.
    third = ds[10]["observation"].reshape(stack, D).numpy()
    assert third[:, 1].tolist() == [max(2 - k, 0) for k in range(stack - 1, -1, -1)]


def test_episode_selection_keeps_the_given_order(root):
    ds = FrameDataset(root, episodes=[2, 0], frame_stack=2)
    assert len(ds) == LENGTHS[2] + LENGTHS[0]
    assert ds.episode_indices == [2, 0]
    for i, (episode, frame) in enumerate(all_frames(LENGTHS, [2, 0])):
        check_item(ds[i], episode, frame, 2)
    # Selecting episode 0 after 2 must not stack episode 2's frames into episode 0's start.
    np.testing.assert_array_equal(ds[LENGTHS[2]]["observation"].numpy(), stacked_obs(0, 0, 2))


def test_getitems_matches_item_by_item(root):
    ds = FrameDataset(root, frame_stack=3)
    indices = [19, 0, 7, 5, 5, 15, 3, 12, -1]
    batch = ds.__getitems__(indices)
    for got, i in zip(batch, indices, strict=True):
        want = ds[i]
        assert got.keys() == want.keys()
        for key in want:
            assert got[key].dtype == want[key].dtype
            assert torch.equal(got[key], want[key])
    assert ds.__getitems__([]) == []


def test_items_do_not_alias_the_cache(root):
    ds = FrameDataset(root)
    item = ds[0]
    item["observation"] += 100
    check_item(ds[0], 0, 0)


def test_discrete_action_comes_back_as_float(tmp_path):
    ds = FrameDataset(write_dataset(tmp_path / "ds", lengths=(3, 2), discrete=True), dtype=torch.float64)
    assert ds.action_dim == 1
    item = ds[4]  # episode 1, frame 1
    assert item["action"].dtype == torch.float64 and item["action"].tolist() == [11.0]
    assert item["observation"].dtype == torch.float64


def test_images_single_and_stacked(tmp_path):
    path = write_dataset(tmp_path / "ds", lengths=(3, 2), image=True)
    ds = FrameDataset(path, with_image=True)
    item = ds[4]
    assert item["image"].dtype == torch.uint8 and item["image"].shape == (H, W, 3)
    np.testing.assert_array_equal(item["image"].numpy(), expected_image(1, 1))
    stacked = FrameDataset(path, with_image=True, frame_stack=3)
    images = stacked[4]["image"].numpy()
    assert images.shape == (3, H, W, 3)
    for k, frame in enumerate([0, 0, 1]):
        np.testing.assert_array_equal(images[k], expected_image(1, frame))
    assert "image" not in FrameDataset(path)[0]


# ------------------------------------------------------------------------------------------------ reading


def test_init_reads_metadata_only(root, count_reads):
    ds = FrameDataset(root, frame_stack=4, cache_episodes=2)
    assert len(ds) == sum(LENGTHS) and ds.locate(16) == (4, 0)
    ds.stats()
    assert count_reads == []
    ds[0]
    assert count_reads == [0]


def test_lru_cache_bound(root, count_reads):
    ds = FrameDataset(root, cache_episodes=2)
    start = [a for a, _ in ds.episode_ranges]
    for episode in [0, 0, 1, 0, 2, 0, 1]:  # 2 evicts 1 (least recent); then 1 must be read again
        ds[start[episode]]
        assert len(ds.cached_episodes) <= 2
    assert count_reads == [0, 1, 2, 1]
    assert ds.cached_episodes == [0, 1]


def test_reads_only_the_needed_columns(root, monkeypatch):
    seen = []
    original = LeRobotReader.episode
    monkeypatch.setattr(
        LeRobotReader, "episode", lambda self, i, columns=None: seen.append(columns) or original(self, i, columns)
    )
    FrameDataset(root)[0]
    assert seen == [["observation.state", "action"]]


def test_pickles_without_data(root):
    ds = FrameDataset(root)
    for i in range(len(ds)):
        ds[i]
    blob = pickle.dumps(ds)
    assert len(blob) < 20_000  # root, metadata and two features' stats; no cached arrays
    clone = pickle.loads(blob)
    assert clone.cached_episodes == []
    check_item(clone[7], 1, 2)


def test_stats_from_stats_json_stacked(root):
    reader = LeRobotReader(root)
    ds = FrameDataset(root, frame_stack=3)
    stats = ds.stats()
    obs, act = reader.stats["observation.state"], reader.stats["action"]
    for key in ("min", "max", "mean", "std"):
        assert stats["observation"][key].shape == (3 * D,) and stats["observation"][key].dtype == torch.float32
        np.testing.assert_allclose(stats["observation"][key].numpy(), np.tile(np.asarray(obs[key]), 3), rtol=1e-6)
        np.testing.assert_allclose(stats["action"][key].numpy(), np.asarray(act[key]), rtol=1e-6)
    # Against the data itself: the observation's second entry is the frame index.
    frames = np.concatenate([np.arange(n) for n in LENGTHS])
    assert stats["observation"]["max"][1] == frames.max() and stats["observation"]["max"][1 + D] == frames.max()
    np.testing.assert_allclose(float(stats["observation"]["mean"][1]), frames.mean(), rtol=1e-6)


# ------------------------------------------------------------------------------------------------ sampler


def item_episodes(ds, indices):
    return {ds.locate(int(i))[0] for i in indices}


def test_sampler_permutation_per_epoch_deterministic_and_varied(many_root):
    ds = FrameDataset(many_root)
    sampler = EpisodeBlockSampler(ds, block_episodes=3, seed=7)
    orders = []
    for epoch in range(3):
        sampler.set_epoch(epoch)
        order = list(sampler)
        assert len(order) == len(sampler) == len(ds)
        assert sorted(order) == list(range(len(ds)))
        orders.append(order)
    assert orders[0] != orders[1] and orders[1] != orders[2]
    again = EpisodeBlockSampler(ds, block_episodes=3, seed=7)
    again.set_epoch(1)
    assert list(again) == orders[1]
    other_seed = EpisodeBlockSampler(ds, block_episodes=3, seed=8)
    other_seed.set_epoch(1)
    assert list(other_seed) != orders[1]
    assert list(EpisodeBlockSampler(ds, shuffle=False)) == list(range(len(ds)))


def test_sampler_blocks_hold_at_most_block_episodes(many_root):
    ds = FrameDataset(many_root)
    sampler = EpisodeBlockSampler(ds, block_episodes=4, seed=1)
    sampler.set_epoch(3)
    blocks = sampler.blocks()
    assert np.concatenate(blocks).tolist() == list(sampler)
    assert len(blocks) == -(-13 // 4)
    seen = set()
    for block in blocks:
        episodes = item_episodes(ds, block)
        assert len(episodes) <= 4
        assert not episodes & seen  # each episode lives in exactly one block
        seen |= episodes
        if len(block) >= 10:  # frames are shuffled within the block (a 3-frame block may come out sorted)
            assert block.tolist() != sorted(block.tolist())
    assert seen == set(range(13))
    # Blocks come in a shuffled episode order, not 0, 1, 2, ...
    assert [min(item_episodes(ds, b)) for b in blocks] != sorted(min(item_episodes(ds, b)) for b in blocks)


def test_block_sampler_reads_each_episode_once(many_root, count_reads):
    ds = FrameDataset(many_root, cache_episodes=4)
    sampler = EpisodeBlockSampler(ds, block_episodes=4, seed=3)
    for i in sampler:
        ds[i]
    assert sorted(count_reads) == list(range(13))


# ------------------------------------------------------------------------------------------------ DataLoader


def frames_of(batches):
    """Multiset of (episode, frame, observation, action) over DataLoader batches."""
    out = Counter()
    for batch in batches:
        for e, f, o, a in zip(
            batch["episode_index"], batch["frame_index"], batch["observation"], batch["action"], strict=True
        ):
            out[(int(e), int(f), tuple(o.tolist()), tuple(a.tolist()))] += 1
    return out


@pytest.mark.parametrize("num_workers", [0, 2])
def test_dataloader_returns_every_frame_once(many_root, num_workers):
    ds = FrameDataset(many_root, frame_stack=2, cache_episodes=3)
    sequential = frames_of({k: v.unsqueeze(0) for k, v in ds[i].items()} for i in range(len(ds)))
    assert sum(sequential.values()) == len(ds) == len(sequential)
    sampler = EpisodeBlockSampler(ds, block_episodes=3, seed=0)
    sampler.set_epoch(1)
    loader = DataLoader(ds, batch_size=16, sampler=sampler, num_workers=num_workers)
    batches = list(loader)
    assert batches[0]["observation"].shape == (16, 2 * D) and batches[0]["action"].shape == (16, N)
    assert frames_of(batches) == sequential
    plain = DataLoader(ds, batch_size=7, shuffle=True, num_workers=num_workers)
    assert frames_of(plain) == sequential


# ------------------------------------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        (
            {"keys": FrameKeys(observation="observation.nope")},
            ["observation_key", "observation.nope", "observation.state"],
        ),
        ({"keys": FrameKeys(action="act")}, ["action_key", "'act'", "next.reward"]),
        ({"keys": FrameKeys(observation="observation.image")}, ["observation.image", "not a feature"]),
        ({"with_image": True}, ["image_key", "observation.image"]),
        ({"frame_stack": 0}, ["frame_stack"]),
        ({"frame_stack": 1.5}, ["frame_stack"]),
        ({"cache_episodes": 0}, ["cache_episodes"]),
        ({"episodes": [0, 5]}, ["episodes", "[5]"]),
        ({"episodes": [-1]}, ["episodes", "[-1]"]),
        ({"episodes": []}, ["episodes"]),
        ({"episodes": [1, 1]}, ["episodes", "more than once"]),
        ({"episodes": ["0"]}, ["episodes"]),
        ({"dtype": torch.int64}, ["dtype"]),
    ],
)
def test_bad_arguments_name_the_argument(root, kwargs, words):
    with pytest.raises(ValueError) as info:
        FrameDataset(root, **kwargs)
    for word in words:
        assert word in str(info.value)


def test_missing_key_is_a_dataset_error(root):
    with pytest.raises(DatasetError, match="available features"):
        FrameDataset(root, keys=FrameKeys(observation="state"))
    # Any numeric 1-D feature may serve (here bool and float32 [1] columns), as a caller's choice.
    ds = FrameDataset(root, keys=FrameKeys(observation="next.done", action="timestamp"))
    assert ds[1]["observation"].tolist() == [0.0] and ds[1]["action"].tolist() == [pytest.approx(0.1)]


def test_image_key_must_be_an_image(tmp_path):
    path = write_dataset(tmp_path / "ds", lengths=(2,), image=True)
    with pytest.raises(DatasetError, match="numeric 1-D"):
        FrameDataset(path, keys=FrameKeys(observation="observation.image"))
    with pytest.raises(DatasetError, match="'image' feature"):
        FrameDataset(path, with_image=True, keys=FrameKeys(image="observation.state"))


def test_bad_indices_and_sampler_arguments(root, tmp_path):
    ds = FrameDataset(root)
    with pytest.raises(IndexError, match="out of range"):
        ds[len(ds)]
    with pytest.raises(IndexError, match="out of range"):
        ds[-len(ds) - 1]
    with pytest.raises(TypeError, match="int"):
        ds["0"]
    with pytest.raises(ValueError, match="block_episodes"):
        EpisodeBlockSampler(ds, block_episodes=0)
    with pytest.raises(ValueError, match="seed"):
        EpisodeBlockSampler(ds, seed=-1)
    with pytest.raises(ValueError, match="epoch"):
        EpisodeBlockSampler(ds).set_epoch(-2)
    with pytest.raises(ValueError, match="FrameDataset"):
        EpisodeBlockSampler(list(range(3)))
    with pytest.raises(DatasetError, match="not found"):
        FrameDataset(tmp_path / "missing")


# ------------------------------------------------------------------------------------------------ ConcatFrames

SECOND = (2, 6)  # the second part's episode lengths


@pytest.fixture(scope="module")
def second_root(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("frames_second") / "ds", lengths=SECOND)


def concat_frames(root, second_root):
    """Episodes 4 and 1 of the first dataset, then every episode of the second."""
    return ConcatFrames([FrameDataset(root, episodes=[4, 1]), FrameDataset(second_root)])


def test_concat_numbers_items_part_after_part(root, second_root):
    ds = concat_frames(root, second_root)
    first = LENGTHS[4] + LENGTHS[1]
    assert len(ds) == first + sum(SECOND) == 15
    assert (ds.observation_dim, ds.action_dim) == (D, N)
    assert ds.episode_ranges == [(0, 4), (4, 7), (7, 9), (9, 15)]
    expected = [(4, f) for f in range(LENGTHS[4])] + [(1, f) for f in range(LENGTHS[1])] + all_frames(SECOND)
    for i, (episode, frame) in enumerate(expected):
        check_item(ds[i], episode, frame)
    # each episode range covers exactly one (part, episode)
    for (start, stop), episode in zip(ds.episode_ranges, [4, 1, 0, 1], strict=True):
        assert {int(ds[i]["episode_index"]) for i in range(start, stop)} == {episode}
        assert [int(ds[i]["frame_index"]) for i in range(start, stop)] == list(range(stop - start))


def test_concat_getitems_matches_item_by_item(root, second_root):
    ds = concat_frames(root, second_root)
    indices = [14, 0, 8, 3, 3, 9, 6, 7, 1, -1, -15]
    batch = ds.__getitems__(indices)
    assert len(batch) == len(indices)
    for got, i in zip(batch, indices, strict=True):
        want = ds[i]
        assert got.keys() == want.keys()
        for key in want:
            assert got[key].dtype == want[key].dtype
            assert torch.equal(got[key], want[key]), (i, key)
    assert ds.__getitems__([]) == []
    for bad in (15, -16):
        with pytest.raises(IndexError, match="out of range"):
            ds.__getitems__([0, bad])


def test_concat_of_other_widths_is_refused(root, second_root, tmp_path):
    with pytest.raises(DatasetError, match=r"differ in \(observation, action\) width"):
        ConcatFrames([FrameDataset(root), FrameDataset(second_root, frame_stack=2)])
    discrete = write_dataset(tmp_path / "discrete", lengths=(3,), discrete=True)
    with pytest.raises(DatasetError, match="width") as info:
        ConcatFrames([FrameDataset(root), FrameDataset(discrete)])
    assert str(discrete) in str(info.value)  # the message names the datasets
    with pytest.raises(ValueError, match="FrameDataset"):
        ConcatFrames([])
    with pytest.raises(ValueError, match="FrameDataset"):
        ConcatFrames([FrameDataset(root), list(range(3))])


def test_block_sampler_over_concat_is_a_permutation_mixing_the_parts(root, second_root):
    ds = ConcatFrames([FrameDataset(root), FrameDataset(second_root)])
    ranges = ds.episode_ranges
    assert len(ranges) == len(LENGTHS) + len(SECOND)
    sampler = EpisodeBlockSampler(ds, block_episodes=2, seed=5)
    for epoch in range(3):
        sampler.set_epoch(epoch)
        order = list(sampler)
        assert len(sampler) == len(ds) and sorted(order) == list(range(len(ds)))
        for block in sampler.blocks():  # a block holds whole episodes, at most two, from either part
            touched = {k for k, (start, stop) in enumerate(ranges) if any(start <= i < stop for i in block)}
            assert 1 <= len(touched) <= 2
            assert sum(ranges[k][1] - ranges[k][0] for k in touched) == len(block)
    loader = DataLoader(ds, batch_size=6, sampler=sampler, num_workers=0)
    seen = Counter()
    for batch in loader:
        assert batch["observation"].shape[1:] == (D,) and batch["action"].shape[1:] == (N,)
        for o in batch["observation"]:
            seen[tuple(o.tolist())] += 1
    assert sum(seen.values()) == len(ds)
    assert seen == Counter(tuple(ds[i]["observation"].tolist()) for i in range(len(ds)))

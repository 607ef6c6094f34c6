"""Training data: npz reading, validation errors, one-off preprocessing, split by episode, batching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from quad_il.learning.dataset import (
    BatchLoader,
    DatasetError,
    episode_hash_fraction,
    episode_keys,
    load_dataset,
    prepare_arrays,
    read_npz,
    split_by_episode,
)
from quad_il.learning.preprocessing import DepthPreprocessor
from quad_il.learning.synthetic import make_synthetic_arrays, write_synthetic_npz

PRE = DepthPreprocessor(24, 32, 10.0)


def save(path: Path, arrays: dict) -> Path:
    np.savez(path, **arrays)
    return path


# ---------------------------------------------------------------------------------------------------- reading
def test_npz_round_trip_with_memory_mapped_depth(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=2, samples_per_episode=3)
    path = save(tmp_path / "d.npz", arrays)
    back = read_npz(path)
    assert isinstance(back["depth_m"], np.memmap)
    assert set(back) == set(arrays)
    for k, v in arrays.items():
        assert np.array_equal(np.asarray(back[k]), v), k
        assert np.asarray(back[k]).dtype == np.asarray(v).dtype, k


def test_compressed_npz_is_read_too(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=2, samples_per_episode=2)
    path = tmp_path / "c.npz"
    np.savez_compressed(path, **arrays)
    back = read_npz(path)
    assert not isinstance(back["depth_m"], np.memmap)
    assert np.array_equal(back["depth_m"], arrays["depth_m"])


def test_prepared_depth_equals_the_policy_preprocessing_of_the_raw_depth(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=3, samples_per_episode=5, height=50, width=70)
    data, info = prepare_arrays(arrays, PRE, "mem")
    assert data.depth_x.dtype == torch.float16 and data.depth_x.shape == (15, 1, 24, 32)
    assert (info.depth_height, info.depth_width, info.num_samples) == (50, 70, 15)
    direct = PRE(torch.from_numpy(arrays["depth_m"].astype(np.float32)))
    assert torch.equal(data.depth_x.float(), direct)  # bit-exact: the cache is lossless
    assert np.isinf(arrays["depth_m"]).any()  # no-return pixels were exercised


def test_several_files_and_directories_are_concatenated_in_order(tmp_path: Path) -> None:
    a = write_synthetic_npz(
        tmp_path / "dir" / "a.npz", num_episodes=2, samples_per_episode=2, first_world_seed=1
    )
    write_synthetic_npz(
        tmp_path / "dir" / "b.npz", num_episodes=1, samples_per_episode=3, first_world_seed=50
    )
    c = write_synthetic_npz(
        tmp_path / "c.npz", num_episodes=1, samples_per_episode=1, height=30, width=40, first_world_seed=90
    )
    data = load_dataset([tmp_path / "dir", c], PRE)
    assert len(data) == 4 + 3 + 1
    assert [s.path for s in data.sources] == [str(a), str(tmp_path / "dir" / "b.npz"), str(c)]
    assert data.world_seed.tolist() == [1, 1, 2, 2, 50, 50, 50, 90]


# ------------------------------------------------------------------------------------------------- bad inputs
def test_other_format_version_is_rejected_naming_the_version(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=1, samples_per_episode=2)
    arrays["format_version"] = np.int64(99)
    with pytest.raises(DatasetError, match=r"format_version 99 is not supported \(this code reads \[1\]\)"):
        load_dataset([save(tmp_path / "v.npz", arrays)], PRE)


def test_empty_dataset_is_rejected(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=1, samples_per_episode=2)
    empty = {k: (v[:0] if np.ndim(v) > 0 else v) for k, v in arrays.items()}
    with pytest.raises(DatasetError, match=r"dataset is empty \(0 records\)"):
        load_dataset([save(tmp_path / "e.npz", empty)], PRE)


def test_empty_or_missing_paths_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no dataset given"):
        load_dataset([], PRE)
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset([tmp_path / "missing.npz"], PRE)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(DatasetError, match="expected an .npz file"):
        load_dataset([tmp_path / "notes.txt"], PRE)
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    with pytest.raises(DatasetError, match="not a readable .npz"):
        load_dataset([tmp_path / "broken.npz"], PRE)


@pytest.mark.parametrize(
    ("key", "index", "message"),
    [
        ("p_world_body", (5, 1), r"NaN/Inf in 'p_world_body' of record 5 \(episode 1\)"),
        ("bspline_ctrl_world", (2, 3, 0), r"NaN/Inf in 'bspline_ctrl_world' of record 2 \(episode 0\)"),
        ("v_world", (6, 2), r"NaN/Inf in 'v_world' of record 6 \(episode 1\)"),
        ("sim_time_s", (7,), r"NaN/Inf in 'sim_time_s' of record 7"),
    ],
)
def test_nan_in_a_record_is_reported_with_record_and_episode(
    tmp_path: Path, key: str, index: tuple[int, ...], message: str
) -> None:
    arrays = make_synthetic_arrays(num_episodes=2, samples_per_episode=4)
    arrays[key] = arrays[key].copy()
    arrays[key][index] = np.nan
    with pytest.raises(DatasetError, match=message):
        load_dataset([save(tmp_path / "n.npz", arrays)], PRE)


def test_negative_depth_is_rejected_but_rep118_specials_are_valid(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=2, samples_per_episode=4, height=16, width=16)
    arrays["depth_m"][3, :2, :2] = [[np.nan, -np.inf], [np.inf, 0.0]]
    data, _ = prepare_arrays(arrays, PRE, "x")
    assert torch.isfinite(data.depth_x).all()
    arrays["depth_m"][6, 5, 5] = -0.5
    with pytest.raises(DatasetError, match=r"negative depth in 'depth_m' of record 6 \(episode 1\)"):
        prepare_arrays(arrays, PRE, "x")


def test_missing_key_wrong_shape_and_bad_quaternion_are_rejected(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=1, samples_per_episode=3)
    missing = dict(arrays)
    del missing["goal_world"]
    with pytest.raises(DatasetError, match=r"missing keys \['goal_world'\]"):
        prepare_arrays(missing, PRE, "x")
    shaped = dict(arrays, v_world=arrays["v_world"][:, :2])
    with pytest.raises(DatasetError, match=r"'v_world' has shape \(3, 2\), expected \(3, 3\)"):
        prepare_arrays(shaped, PRE, "x")
    quat = dict(arrays, q_world_body=arrays["q_world_body"] * 2)
    with pytest.raises(DatasetError, match="not a unit quaternion"):
        prepare_arrays(quat, PRE, "x")


def test_inconsistent_local_frame_is_rejected(tmp_path: Path) -> None:
    arrays = make_synthetic_arrays(num_episodes=1, samples_per_episode=3)
    arrays["bspline_ctrl_local"] = arrays["bspline_ctrl_local"].copy()
    arrays["bspline_ctrl_local"][1, :, 1] *= -1  # mirrored y: another frame convention
    with pytest.raises(DatasetError, match="bspline_ctrl_local of record 1 differs"):
        prepare_arrays(arrays, PRE, "x")


def test_sources_with_different_bspline_layouts_are_not_mixed(tmp_path: Path) -> None:
    a = write_synthetic_npz(tmp_path / "a.npz", num_episodes=1, samples_per_episode=2)
    b = write_synthetic_npz(tmp_path / "b.npz", num_episodes=1, samples_per_episode=2, num_ctrl_pts=8)
    with pytest.raises(DatasetError, match="disagree on the B-spline layout"):
        load_dataset([a, b], PRE)


# ------------------------------------------------------------------------------------------------------ split
def test_split_is_by_episode_seeded_and_covers_every_sample() -> None:
    arrays = make_synthetic_arrays(num_episodes=20, samples_per_episode=3)
    ws, ep = arrays["world_seed"], arrays["episode_id"]
    split = split_by_episode(ws, ep, 0.1, seed=4)
    assert len(split.val_episodes) == 2 and len(split.train_episodes) == 18
    assert not set(split.train_episodes) & set(split.val_episodes)
    assert sorted(np.concatenate([split.train_idx, split.val_idx]).tolist()) == list(range(60))
    keys = list(zip(ws.tolist(), ep.tolist(), strict=True))
    assert {keys[i] for i in split.train_idx} == set(split.train_episodes)
    assert {keys[i] for i in split.val_idx} == set(split.val_episodes)
    again = split_by_episode(ws, ep, 0.1, seed=4)
    assert np.array_equal(again.val_idx, split.val_idx)
    others = {tuple(split_by_episode(ws, ep, 0.1, seed=s).val_episodes) for s in range(10)}
    assert len(others) > 1


def _keys(num_worlds: int, first_seed: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Two samples of each of `num_worlds` episodes (world seeds from `first_seed`, episode id 1)."""
    ws = np.repeat(np.arange(first_seed, first_seed + num_worlds, dtype=np.uint64), 2)
    return ws, np.ones(len(ws), dtype=np.int64)


def test_hashed_split_keeps_every_episode_on_its_side_when_datasets_are_added() -> None:
    ws, ep = _keys(300)
    more_ws, more_ep = _keys(500, first_seed=5000)  # the next round's dataset
    before = split_by_episode(ws, ep, 0.1, seed=3, method="hashed")
    after = split_by_episode(
        np.concatenate([ws, more_ws]), np.concatenate([ep, more_ep]), 0.1, seed=3, method="hashed"
    )
    assert set(before.val_episodes) <= set(after.val_episodes)
    assert set(before.train_episodes) <= set(after.train_episodes)
    assert not set(after.train_episodes) & set(after.val_episodes)
    assert sorted(np.concatenate([after.train_idx, after.val_idx]).tolist()) == list(range(1600))
    # The permuted split (the default) moves episodes between the sides when data is added.
    p_before = split_by_episode(ws, ep, 0.1, seed=3)
    p_after = split_by_episode(np.concatenate([ws, more_ws]), np.concatenate([ep, more_ep]), 0.1, seed=3)
    assert set(p_before.val_episodes) & set(p_after.train_episodes)


def test_hashed_split_is_seeded_and_holds_the_fraction_on_average() -> None:
    ws, ep = _keys(4000)
    split = split_by_episode(ws, ep, 0.1, seed=0, method="hashed")
    assert 0.085 < len(split.val_episodes) / 4000 < 0.115
    assert split.val_episodes == split_by_episode(ws, ep, 0.1, seed=0, method="hashed").val_episodes
    assert split.val_episodes != split_by_episode(ws, ep, 0.1, seed=1, method="hashed").val_episodes
    assert episode_hash_fraction((1000, 1), 0) == episode_hash_fraction((1000, 1), 0)
    assert 0.0 <= episode_hash_fraction((1000, 1), 0) < 1.0


def test_hashed_split_keeps_an_episode_on_each_side() -> None:
    ws, ep = _keys(2)
    for fraction in (0.001, 0.999):
        split = split_by_episode(ws, ep, fraction, seed=0, method="hashed")
        assert len(split.val_episodes) == 1 and len(split.train_episodes) == 1


def test_an_unknown_split_method_is_refused_naming_it() -> None:
    ws, ep = _keys(4)
    with pytest.raises(ValueError, match="split method 'random': one of permuted, hashed"):
        split_by_episode(ws, ep, 0.1, seed=0, method="random")


def test_same_episode_id_in_different_worlds_are_different_episodes() -> None:
    ws = np.array([1, 1, 2, 2, 3, 3], dtype=np.uint64)
    ep = np.zeros(6, dtype=np.int64)
    keys, inverse = episode_keys(ws, ep)
    assert keys == [(1, 0), (2, 0), (3, 0)] and inverse.tolist() == [0, 0, 1, 1, 2, 2]
    split = split_by_episode(ws, ep, 0.3, seed=0)
    assert len(split.val_episodes) == 1 and len(split.val_idx) == 2


def test_train_episode_fraction_subsets_training_and_keeps_validation() -> None:
    arrays = make_synthetic_arrays(num_episodes=21, samples_per_episode=2)
    full = split_by_episode(arrays["world_seed"], arrays["episode_id"], 0.1, 7)
    quarter = split_by_episode(
        arrays["world_seed"], arrays["episode_id"], 0.1, 7, train_episode_fraction=0.25
    )
    assert quarter.val_episodes == full.val_episodes
    assert set(quarter.train_episodes) < set(full.train_episodes)
    assert len(quarter.train_episodes) == 5 and len(quarter.unused_episodes) == 14


def test_a_single_episode_cannot_be_split() -> None:
    with pytest.raises(DatasetError, match="at least 2 episodes"):
        split_by_episode(np.ones(5, dtype=np.uint64), np.zeros(5, dtype=np.int64), 0.1, 0)


# --------------------------------------------------------------------------------------------------- batching
def test_batch_order_is_a_function_of_seed_and_epoch_and_independent_of_workers() -> None:
    data, _ = prepare_arrays(make_synthetic_arrays(num_episodes=5, samples_per_episode=5), PRE, "m")
    targets = torch.arange(len(data) * 2, dtype=torch.float32).reshape(len(data), 2)
    idx = np.arange(3, 25)
    orders = []
    for workers in (0, 2):
        loader = BatchLoader(data, targets, idx, 4, shuffle=True, seed=9, drop_last=True, num_workers=workers)
        assert len(loader) == 5
        batches = list(loader.epoch(3))
        assert all(len(b.indices) == 4 for b in batches)
        for b in batches:
            assert torch.equal(b.target, targets[torch.from_numpy(b.indices)])
            assert torch.equal(b.depth_x, data.depth_x[torch.from_numpy(b.indices)].float())
        orders.append(np.concatenate([b.indices for b in batches]))
    assert np.array_equal(orders[0], orders[1])
    loader = BatchLoader(data, targets, idx, 4, shuffle=True, seed=9)
    assert not np.array_equal(loader.order(3), loader.order(4))
    assert sorted(loader.order(3).tolist()) == idx.tolist()
    plain = BatchLoader(data, targets, idx, 5, shuffle=False)
    assert np.concatenate([b.indices for b in plain.epoch(0)]).tolist() == idx.tolist()
    assert len(plain) == 5  # 22 samples: last batch of 2 kept


# ---------------------------------------------------------------------------------- shards of the real writer
def real_shards(out: Path, seed: int, records: int = 36) -> Path:
    """A shard dataset written by cpp_data_collector's own writer (skips where the tool is not built)."""
    from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset

    try:
        find_collector_tool("write_synthetic_dataset")
    except FileNotFoundError as e:
        pytest.skip(f"cpp_data_collector not built: {e}")
    return write_synthetic_dataset(
        out, seed=seed, records=records, width=64, height=48, records_per_episode=9
    )


def test_shards_read_directly_equal_their_postprocessed_npz(tmp_path: Path) -> None:
    from quad_il.data.postprocess import postprocess_datasets

    shards = real_shards(tmp_path / "ds", seed=3)
    npz = postprocess_datasets([shards]).save(tmp_path / "ds.npz")
    direct = load_dataset([shards], PRE)
    via_npz = load_dataset([npz], PRE)
    assert len(direct) == 36 and direct.sources[0].path == str(shards)
    for name in ("depth_x", "p_world_body", "q_world_body", "goal_world", "ctrl_world", "ctrl_local"):
        assert torch.equal(getattr(direct, name), getattr(via_npz, name)), name
    assert np.array_equal(direct.world_seed, via_npz.world_seed)
    assert np.array_equal(direct.episode_id, via_npz.episode_id)
    assert len(split_by_episode(direct.world_seed, direct.episode_id, 0.25, 0).val_episodes) == 1


def test_a_shard_directory_is_prepared_shard_by_shard_as_a_whole(tmp_path: Path) -> None:
    from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
    from quad_il.learning.dataset import prepare_arrays, shard_dir_arrays

    try:
        find_collector_tool("write_synthetic_dataset")
    except FileNotFoundError as e:
        pytest.skip(f"cpp_data_collector not built: {e}")
    # 64x48 records of about 10 KB, shards of 0.05 MB: several shards, episodes across their boundaries.
    path = write_synthetic_dataset(
        tmp_path / "ds", seed=5, records=40, width=64, height=48, records_per_episode=7, shard_size_mb=0.05
    )
    assert len(list(path.glob("shard_*"))) >= 3
    by_shard = load_dataset([path], PRE)
    whole = prepare_arrays(shard_dir_arrays(path), PRE, str(path))[0]
    assert len(by_shard) == 40 and [(s.path, s.num_samples) for s in by_shard.sources] == [(str(path), 40)]
    assert by_shard.sources == whole.sources
    for name in (
        "depth_x",
        "p_world_body",
        "v_world",
        "q_world_body",
        "goal_world",
        "ctrl_world",
        "ctrl_local",
    ):
        assert torch.equal(getattr(by_shard, name), getattr(whole, name)), name
    for name in ("episode_id", "world_seed", "sim_time_s"):
        assert np.array_equal(getattr(by_shard, name), getattr(whole, name)), name


def test_a_directory_that_is_no_dataset_is_rejected(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="cannot read as a shard dataset"):
        load_dataset([tmp_path / "empty"], PRE)


def test_float16_negative_check_on_bits_equals_the_float_comparison() -> None:
    from quad_il.learning.dataset import _negative_finite_rows

    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2**16, size=(200, 37), dtype=np.uint16)  # every float16 kind: specials, subnormals
    bits[:20] = np.array([0x0000, 0x8000, 0xFC00, 0x7C00, 0xFE00, 0x7E00, 0x8001, 0xFBFF], dtype=np.uint16)[
        rng.integers(0, 8, size=(20, 37))
    ]
    # Rows 20..39: only +-0, +-inf and NaNs of both signs: valid depth, nothing negative.
    bits[20:40] = np.array([0x0000, 0x8000, 0xFC00, 0x7C00, 0xFE00, 0x7E00], dtype=np.uint16)[
        rng.integers(0, 6, size=(20, 37))
    ]
    halves = bits.view(np.float16)
    got = _negative_finite_rows(halves)
    assert np.array_equal(got, _negative_finite_rows(halves.astype(np.float32)))
    assert not got[20:40].any() and got[40:].all()

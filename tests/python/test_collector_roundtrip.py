"""Round trip: records written by the C++ writer read back identically by the C++ and the Python readers."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from quad_il.data import decode_depth_codes, load_dataset, open_dataset
from quad_il.data.format import RECORD_MAGIC, layout_json
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset

W, H = 40, 30


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # About 6 records per shard: several completed shards plus a short last one.
    out = tmp_path_factory.mktemp("rt") / "ds"
    return write_synthetic_dataset(
        out, seed=5, records=27, width=W, height=H, records_per_episode=10, shard_size_mb=0.06
    )


def cpp_dump(path: Path) -> list[dict]:
    tool = find_collector_tool("read_dataset")
    out = subprocess.run(
        [str(tool), "dump", str(path), "--format", "jsonl", "--depth", "full"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return [json.loads(line) for line in out.splitlines()]


def test_cpp_and_python_readers_return_identical_records(dataset: Path) -> None:
    ds = open_dataset(dataset)
    assert len(ds.shards) >= 4
    assert ds.verify().ok
    dumped = cpp_dump(dataset)
    assert len(dumped) == len(ds) == 27
    scalar_fields = [
        "seq",
        "episode_id",
        "world_seed",
        "sim_time_s",
        "depth_stamp_s",
        "odom_stamp_s",
        "bspline_start_time_s",
        "bspline_yaw_dt_s",
        "bspline_traj_id",
        "bspline_order",
        "plan_status_code",
        "t_map_update_ms",
        "t_frontend_ms",
        "t_optimization_ms",
        "t_total_ms",
    ]
    for i, cpp in enumerate(dumped):
        s, k = ds.locate(i)
        assert cpp["shard"] == ds.shards[s].name and cpp["index"] == k
        rec = ds[i]
        assert int(rec["magic"]) == RECORD_MAGIC
        for name in scalar_fields:
            # The C++ dump prints doubles with 17 significant digits: they parse back to the same double.
            assert rec[name].item() == cpp[name], (i, name)
        for name in ["p_world_body", "v_world", "q_world_body", "w_body", "goal_world"]:
            assert rec[name].tolist() == cpp[name], (i, name)
        n_knots, n_ctrl, n_yaw = int(rec["num_knots"]), int(rec["num_ctrl_pts"]), int(rec["num_yaw_pts"])
        assert rec["knots"][:n_knots].tolist() == cpp["knots"]
        assert rec["ctrl_pts_world"][:n_ctrl].tolist() == cpp["ctrl_pts_world"]
        assert rec["yaw_pts"][:n_yaw].tolist() == cpp["yaw_pts"]
        # Unused slots are zero, so equal plans give byte-equal records.
        assert not rec["knots"][n_knots:].any() and not rec["ctrl_pts_world"][n_ctrl:].any()
        assert rec["plan_status_text"] == cpp["plan_status_text"].encode("latin-1")
        assert (cpp["depth_width"], cpp["depth_height"]) == (W, H)
        assert rec["depth_code"].ravel().tolist() == cpp["depth_code"]


def test_shard_records_are_a_zero_copy_read_only_memory_map(dataset: Path) -> None:
    shard = open_dataset(dataset).shards[0]
    assert isinstance(shard._raw, np.memmap)
    records = shard.records
    assert not records.flags.owndata and not records.flags.writeable
    assert np.shares_memory(records, shard._raw)
    depth = records["depth_code"]
    assert depth.shape == (shard.num_records, H, W) and depth.dtype == np.uint16
    assert np.shares_memory(depth, shard._raw)


def test_header_describes_the_layout_and_camera(dataset: Path) -> None:
    header = open_dataset(dataset).header
    assert header is not None
    assert (header.image_width, header.image_height, header.max_ctrl_pts) == (W, H, 128)
    assert header.layout_json == layout_json(W, H, 136, 128, 128)
    assert header.camera_fx_px == pytest.approx(387.2 * W / 640)


def test_depth_holds_every_rep118_kind_and_decodes_to_metres(dataset: Path) -> None:
    loaded = load_dataset(dataset)
    codes = loaded["depth_code"]
    depth = loaded.depth_m()
    assert depth.dtype == np.float32 and depth.shape == codes.shape
    assert np.isnan(depth[codes == 0]).all() and (codes == 0).any()
    assert np.isposinf(depth[codes == 65535]).all() and (codes == 65535).any()
    valid = (codes >= 2) & (codes < 65535)
    np.testing.assert_array_equal(depth[valid], (codes[valid] / 1000.0).astype(np.float32))
    np.testing.assert_array_equal(
        decode_depth_codes(codes, "float16")[valid], (codes[valid] / 1000.0).astype(np.float16)
    )


def test_load_dataset_concatenates_shards_and_datasets_with_their_sources(
    dataset: Path, tmp_path: Path
) -> None:
    other = write_synthetic_dataset(tmp_path / "other", seed=6, records=4, width=W, height=H)
    loaded = load_dataset([dataset, other])
    assert len(loaded) == 31
    np.testing.assert_array_equal(loaded["seq"][:27], np.arange(27))
    assert loaded.source(27).endswith("other/shard_000000.qdr record 0")
    ds = open_dataset(dataset)
    for i in range(27):
        s, k = ds.locate(i)
        assert loaded.source(i) == f"{dataset / ds.shards[s].name} record {k}"
    assert len(loaded.manifests) == 2 and loaded.manifests[0]["counts"]["written"] == 27


def test_manifest_records_config_seeds_counts_and_shards(dataset: Path) -> None:
    m = open_dataset(dataset).manifest
    assert m is not None
    assert m["status"] == "complete"
    assert m["counts"] == {"submitted": 27, "written": 27, "dropped": 0, "rejected": 0, "lost": 0}
    assert [e["records"] for e in m["episodes"]] == [10, 10, 7]
    assert m["world_seeds"] == [e["world_seed"] for e in m["episodes"]]
    assert sum(s["records"] for s in m["shards"]) == 27
    assert m["config"]["image_width"] == W
    assert m["run_info"]["synthetic_seed"] == "5"


def test_same_seed_gives_byte_identical_shards(dataset: Path, tmp_path: Path) -> None:
    again = write_synthetic_dataset(
        tmp_path / "again", seed=5, records=27, width=W, height=H, records_per_episode=10, shard_size_mb=0.06
    )
    for a, b in zip(sorted(dataset.glob("shard_*")), sorted(again.glob("shard_*")), strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name

"""quad_il.data.compact: a dataset's depth area-pooled to the network's input size, everything else kept.

Source: the C++ writer's synthetic dataset at 40x30 (several shards), with REP 118 specials, far and near
pixels, a cell made only of too-near pixels and seqs with gaps written into it; compacted to 16x12. Both
40/16 and 30/12 are 2.5, so every adaptive-pooling cell is 3x3 pixels.
"""

from __future__ import annotations

import hashlib
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import quad_il.data.compact as compact_mod
from quad_il.data import NotADatasetError, open_dataset
from quad_il.data.compact import (
    CompactError,
    compact_dataset,
    main,
    parse_size,
    scaled_intrinsics,
    training_defaults,
)
from quad_il.data.format import HEADER_SIZE, encode_depth_m
from quad_il.data.shards import ShardReader
from quad_il.learning.config import load_config
from quad_il.learning.dataset import DatasetError as LearningDatasetError
from quad_il.learning.dataset import load_dataset as learning_load_dataset
from quad_il.learning.preprocessing import DepthPreprocessor
from quad_il.tools.repo import repo_path

W, H = 40, 30
W2, H2 = 16, 12
MAX_DEPTH_M = 10.0
RECORDS = 24

# Bounds of |DepthPreprocessor(compacted) - DepthPreprocessor(source)|, both read back from their shards.
# Reader path (float32 metres, the readers' decoding, which compaction uses too): compaction pools exactly
# the preprocessor's float32 cell means P; the stored code is P rounded to 1 mm (+-0.5 mm, 2e-4 before
# normalisation only for 0 < P < 1.5 mm, stored as 2 mm). So the two preprocessor inputs to the final float16
# rounding differ by <= 0.5 mm / max_depth_m = 5e-5, less than one float16 step in [0.5, 1] (2^-11), and the
# rounded values are at most one step apart: 2^-11 = 4.9e-4 (half a float16 ulp of 1.0). Measured: 2^-11 here
# and on data/dagger_r1a compacted to 96x96 (0.9 % of 46.9M values of 5086 records differ, all by one step).
BOUND_READER = 2.0**-11
# Training path (learning.dataset reads shards as float16 metres, docs/data_format.md): the source's pixels
# and the compacted cell each carry float16's decoding error (<= 3.9 mm below 16 m) besides the 0.5 mm of
# the code, <= 8.3 mm / 10 m = 8.3e-4 before the final rounding: at most two float16 steps, 2^-10 = 9.8e-4.
# Measured: 2^-11 here; 2^-10 on data/dagger_r1a at 96x96 (185 of 46.9M values; 2.2M differ by one step).
BOUND_TRAINING = 2.0**-10


def _rewrite_records(ds_dir: Path, change) -> None:  # noqa: ANN001
    """Calls change(global index, record) on every record of every shard in place and fixes its CRC."""
    i = 0
    for path in sorted(ds_dir.glob("shard_*.qdr*")):
        reader = ShardReader(path)
        n, rs, dtype = reader.num_records, reader.header.record_size, reader.dtype
        reader.close()
        raw = np.memmap(path, dtype=np.uint8, mode="r+")
        for j in range(n):
            rec_bytes = raw[HEADER_SIZE + j * rs : HEADER_SIZE + (j + 1) * rs]
            change(i, rec_bytes.view(dtype)[0])
            rec_bytes[rs - 4 :] = np.frombuffer(
                zlib.crc32(rec_bytes[: rs - 4]).to_bytes(4, "little"), np.uint8
            )
            i += 1
        raw.flush()
        del raw


def _specials(i: int, rec: np.void) -> None:
    d = rec["depth_code"]
    if i == 0:
        d[0:3, 0:3] = 1  # one whole pooling cell too near (-inf)
    d[4, 7] = 1  # -inf
    d[5, 8] = 0  # NaN (invalid)
    d[6, 9] = 65535  # +inf (no return)
    d[7, 10] = 30000  # far: 30 m, clamped
    d[8, 11] = 2  # near: 2 mm
    d[H - 1, W - 1 - i % 5] = 9999  # just below max depth
    rec["seq"] = 3 * i + 1  # seqs with gaps (dropped records)


def _digest(path: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(path.iterdir())}


@pytest.fixture(scope="module")
def src(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset

    try:
        find_collector_tool("write_synthetic_dataset")
    except FileNotFoundError as e:
        pytest.skip(f"cpp_data_collector not built: {e}")
    out = write_synthetic_dataset(
        tmp_path_factory.mktemp("compact") / "src",
        seed=5,
        records=RECORDS,
        width=W,
        height=H,
        records_per_episode=8,
        shard_size_mb=0.05,  # 6 records per shard: several shards
    )
    _rewrite_records(out, _specials)
    (out / "episodes.csv").write_text("index,seed,outcome\n0,5,goal_reached\n")
    (out / "dagger_summary.yaml").write_text("complete: true\nepisodes: 3\n")
    return out


@pytest.fixture(scope="module")
def dst(src: Path) -> Path:
    before = _digest(src)
    out = src.parent / "dst"
    summary = compact_dataset(src, out, W2, H2, MAX_DEPTH_M, progress=False)
    assert _digest(src) == before  # the source is only read
    assert summary.records == RECORDS and summary.dst_size == (W2, H2) and summary.src_size == (W, H)
    assert summary.src_bytes > summary.dst_bytes and summary.ratio == summary.src_bytes / summary.dst_bytes
    return out


def _depth_m(path: Path) -> np.ndarray:
    """All depth images of a dataset as the reader returns them (float32 metres, REP 118 specials)."""
    ds = open_dataset(path)
    return np.concatenate([s.depth_m(np.arange(len(s))) for s in ds.shards])


# ------------------------------------------------------------------------------------------------ round trip
def test_every_field_but_the_depth_is_copied_and_the_manifest_records_the_derivation(
    src: Path, dst: Path
) -> None:
    a, b = open_dataset(src), open_dataset(dst)
    assert len(a.shards) > 2 and len(b) == len(a) == RECORDS
    assert b.verify().ok and b.status == "complete"
    ra = np.concatenate([np.array(s.records) for s in a.shards])
    rb = np.concatenate([np.array(s.records) for s in b.shards])
    assert ra.dtype.names == rb.dtype.names
    for name in ra.dtype.names:
        if name in ("depth_code", "crc32"):
            continue
        assert ra[name].tobytes() == rb[name].tobytes(), name
    assert rb["seq"].tolist() == [3 * i + 1 for i in range(RECORDS)]
    assert rb["depth_code"].shape == (RECORDS, H2, W2)

    ma, mb = a.manifest, b.manifest
    assert mb["format_version"] == 1 and mb["counts"]["written"] == RECORDS
    assert (mb["config"]["image_width"], mb["config"]["image_height"]) == (W2, H2)
    assert mb["episodes"] == ma["episodes"] and mb["world_seeds"] == ma["world_seeds"]
    assert [s["first_seq"] for s in mb["shards"]][0] == 1 and mb["shards"][-1]["last_seq"] == 3 * RECORDS - 2
    cam, cam0 = mb["config"]["camera"], ma["config"]["camera"]
    assert cam["fx_px"] == pytest.approx(cam0["fx_px"] * W2 / W, rel=1e-15)
    assert cam["fy_px"] == pytest.approx(cam0["fy_px"] * H2 / H, rel=1e-15)
    assert cam["cx_px"] == pytest.approx((cam0["cx_px"] + 0.5) * W2 / W - 0.5, rel=1e-15)
    assert cam["cy_px"] == pytest.approx((cam0["cy_px"] + 0.5) * H2 / H - 0.5, rel=1e-15)
    hdr = b.header
    assert hdr is not None and (hdr.camera_fx_px, hdr.camera_cx_px) == (cam["fx_px"], cam["cx_px"])
    assert (hdr.image_width, hdr.image_height, hdr.format_version) == (W2, H2, 1)
    for key, value in ma["run_info"].items():
        assert mb["run_info"][key] == value
    assert mb["run_info"]["derived_from"] == str(src.resolve())
    assert mb["run_info"]["compacted"] == "16x12 area-pooled, max_depth_m 10"
    for name in ("episodes.csv", "dagger_summary.yaml"):
        assert (dst / name).read_bytes() == (src / name).read_bytes()
    # Pixel centres at integer coordinates: the image's centre stays the centre; unknown (0) stays 0.
    assert scaled_intrinsics((193.6, 193.6, 159.5, 119.5), (320, 240), (96, 96)) == (58.08, 77.44, 47.5, 47.5)
    assert scaled_intrinsics((0.0, 0.0, 0.0, 0.0), (W, H), (W2, H2)) == (0.0, 0.0, 0.0, 0.0)


def test_the_depth_is_the_preprocessors_area_mean_in_millimetre_codes(src: Path, dst: Path) -> None:
    d = torch.from_numpy(_depth_m(src)).unsqueeze(1)
    d.clamp_(0.0, MAX_DEPTH_M)
    d.nan_to_num_(nan=MAX_DEPTH_M)
    pooled = F.adaptive_avg_pool2d(d, [H2, W2]).squeeze(1).numpy()
    expected = encode_depth_m(pooled)
    expected[pooled == 0.0] = 1  # a cell of too-near pixels only: too near, not invalid
    codes = np.concatenate([np.array(s.records["depth_code"]) for s in open_dataset(dst).shards])
    assert np.array_equal(codes, expected)
    assert codes[0, 0, 0] == 1 and (codes[1:, 0, 0] > 1).all() and codes.max() <= 10000


def test_preprocessed_compact_depth_equals_the_sources_within_float16_rounding(src: Path, dst: Path) -> None:
    pre = DepthPreprocessor(H2, W2, MAX_DEPTH_M)
    a = pre(torch.from_numpy(_depth_m(src)))
    b = pre(torch.from_numpy(_depth_m(dst)))
    reader_diff = float((a - b).abs().max())
    # What training computes: learning.dataset reads both shard directories (float16 metres) and caches the
    # preprocessed depth.
    ta = learning_load_dataset([src], pre).depth_x.float()
    tb = learning_load_dataset([dst], pre).depth_x.float()
    training_diff = float((ta - tb).abs().max())
    print(f"max |pre(compact) - pre(source)|: reader {reader_diff:.3g}, training {training_diff:.3g}")
    assert reader_diff <= BOUND_READER
    assert training_diff <= BOUND_TRAINING
    assert float(a[0, 0, 0, 0]) == float(b[0, 0, 0, 0]) == 0.0  # the too-near cell stays 0
    assert torch.isfinite(b).all() and int((a != b).sum()) < a.numel() // 10


def test_mirroring_commutes_with_compaction(src: Path, dst: Path) -> None:
    """Flip then compact == compact then flip: the pooling cells are mirror-symmetric. The codes are equal
    exactly: a 3x3 cell's mean of whole millimetres is k/9 mm, at least 1/18 mm from a rounding boundary, so
    the summation order (reversed by the flip) cannot change a code."""
    flipped = src.parent / "src_flipped"
    shutil.copytree(src, flipped)

    def flip(_i: int, rec: np.void) -> None:
        rec["depth_code"] = rec["depth_code"][:, ::-1].copy()

    _rewrite_records(flipped, flip)
    out = compact_dataset(flipped, src.parent / "dst_flipped", W2, H2, MAX_DEPTH_M, progress=False).dst
    codes = np.concatenate([np.array(s.records["depth_code"]) for s in open_dataset(dst).shards])
    codes_f = np.concatenate([np.array(s.records["depth_code"]) for s in open_dataset(out).shards])
    assert np.array_equal(codes_f, codes[:, :, ::-1])
    assert not np.array_equal(codes_f, codes)


# ---------------------------------------------------------------------------------------------------- errors
def test_missing_and_incomplete_sources_are_refused(src: Path, tmp_path: Path) -> None:
    with pytest.raises(NotADatasetError, match=r"nope: no such dataset directory"):
        compact_dataset(tmp_path / "nope", tmp_path / "o1", W2, H2, MAX_DEPTH_M, progress=False)
    inc = tmp_path / "inc"
    shutil.copytree(src, inc)
    manifest = inc / "manifest.yaml"
    manifest.write_text(manifest.read_text().replace("status: complete", "status: incomplete"))
    with pytest.raises(CompactError, match=r"inc: dataset is incomplete \(manifest status incomplete\)"):
        compact_dataset(inc, tmp_path / "o2", W2, H2, MAX_DEPTH_M, progress=False)
    last = sorted(inc.glob("shard_*.qdr"))[-1]
    last.rename(last.with_name(last.name + ".partial"))
    with pytest.raises(CompactError, match=rf"incomplete .*partial shard {last.name}\.partial"):
        compact_dataset(inc, tmp_path / "o3", W2, H2, MAX_DEPTH_M, progress=False)
    assert not any((tmp_path / o).exists() for o in ("o1", "o2", "o3"))


def test_a_non_empty_output_directory_is_refused(src: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(CompactError, match=r"out: output directory exists and is not empty"):
        compact_dataset(src, out, W2, H2, MAX_DEPTH_M, progress=False)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    with pytest.raises(CompactError, match=r"must not be the source dataset"):
        compact_dataset(src, src / "inside", W2, H2, MAX_DEPTH_M, progress=False)


def test_target_sizes_that_do_not_shrink_are_refused(src: Path, tmp_path: Path) -> None:
    with pytest.raises(
        CompactError, match=r"target size 48x12 is larger than .*src's stored depth 40x30 in width"
    ):
        compact_dataset(src, tmp_path / "o", 48, 12, MAX_DEPTH_M, progress=False)
    with pytest.raises(CompactError, match=r"in width and height"):
        compact_dataset(src, tmp_path / "o", 41, 31, MAX_DEPTH_M, progress=False)
    with pytest.raises(CompactError, match=r"stored depth is already 40x30, the target size: nothing to do"):
        compact_dataset(src, tmp_path / "o", 40, 30, MAX_DEPTH_M, progress=False)
    with pytest.raises(CompactError, match=r"max_depth_m 70.0 must be in \(0, 65.534\]"):
        compact_dataset(src, tmp_path / "o", W2, H2, 70.0, progress=False)
    assert not (tmp_path / "o").exists()


def test_a_failure_after_writing_removes_the_output(
    src: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*_args: object) -> None:
        raise CompactError("injected")

    monkeypatch.setattr(compact_mod, "_verify_output", broken)
    with pytest.raises(CompactError, match="injected"):
        compact_dataset(src, tmp_path / "o", W2, H2, MAX_DEPTH_M, progress=False)
    assert not (tmp_path / "o").exists()


def test_size_text_is_parsed_strictly() -> None:
    assert parse_size("96x96") == (96, 96) and parse_size(" 16X12 ") == (16, 12)
    for bad in ("96", "96x", "x96", "96by96", "0x12", "16x12x3", "-16x12", "16.0x12"):
        with pytest.raises(ValueError, match="expected WIDTHxHEIGHT"):
            parse_size(bad)


# ------------------------------------------------------------------------------------------------------- CLI
def test_cli_compacts_prints_the_sizes_and_refuses_bad_arguments(
    src: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cli"
    assert main([str(src), "--out", str(out), "--size", f"{W2}x{H2}", "--quiet"]) == 0
    text = capsys.readouterr().out
    size = open_dataset(out).manifest["run_info"]["compacted"]
    assert size == "16x12 area-pooled, max_depth_m 10"
    src_bytes = sum(p.stat().st_size for p in src.iterdir())
    dst_bytes = sum(p.stat().st_size for p in out.iterdir())
    assert f"{src_bytes} bytes -> {dst_bytes} bytes ({src_bytes / dst_bytes:.2f}x smaller)" in text

    with pytest.raises(SystemExit) as e:
        main([str(src), "--out", str(tmp_path / "x"), "--size", "96by96"])
    assert e.value.code == 2
    assert "argument --size: invalid size '96by96': expected WIDTHxHEIGHT" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main([str(src)])
    assert e.value.code == 2 and "the following arguments are required: --out" in capsys.readouterr().err
    assert main([str(tmp_path / "nope"), "--out", str(tmp_path / "y"), "--quiet"]) == 1
    assert "compact: error: " in (err := capsys.readouterr().err) and "nope: no such dataset directory" in err
    # Defaults (96x96 > 40x30): refused as an upsampling.
    assert main([str(src), "--out", str(tmp_path / "z"), "--quiet"]) == 1
    assert "target size 96x96 is larger than" in capsys.readouterr().err


def test_cli_help_documents_every_option_and_the_defaults_are_the_training_configs(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    model = load_config([repo_path("config", "train.yaml")]).model
    assert training_defaults() == (model.input_width, model.input_height, model.max_depth_m)
    for option in ("--out DST", "--size WxH", "--max-depth-m", "--quiet", "SRC"):
        assert option in text
    assert f"(default: {model.input_width}x{model.input_height})" in text
    assert f"(default: {model.max_depth_m})" in text


# ------------------------------------------------------------------------------------------- training loader
def test_the_training_loader_refuses_depth_smaller_than_the_network_input(dst: Path) -> None:
    with pytest.raises(
        LearningDatasetError, match=r"dst: depth is stored at 16x12, smaller than the network input 16x16"
    ):
        learning_load_dataset([dst], DepthPreprocessor(16, 16, MAX_DEPTH_M))
    with pytest.raises(LearningDatasetError, match=r"smaller than the network input 24x8"):
        learning_load_dataset([dst], DepthPreprocessor(8, 24, MAX_DEPTH_M))
    assert len(learning_load_dataset([dst], DepthPreprocessor(12, 16, MAX_DEPTH_M))) == RECORDS

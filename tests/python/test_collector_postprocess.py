"""Postprocessing: own de Boor against hand-computed values and scipy, the documented resampling, and the npz
content equal to the shards' content after that resampling."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.interpolate
import scipy.linalg
from scipy.spatial.transform import Rotation

from quad_il.data import FixedSizeArrays, FormatVersionError, load_dataset, open_dataset, records_to_arrays
from quad_il.data.bspline import de_boor, evaluate, uniform_knots
from quad_il.data.format import DatasetError, record_dtype
from quad_il.data.postprocess import (
    NPZ_ARRAYS,
    ResampleConfig,
    expert_samples,
    local_to_world,
    world_to_local,
    yaw_from_quaternion_xyzw,
)
from quad_il.data.synthetic import write_synthetic_dataset

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "training_only" / "cpp_dataset_postprocessing.py"
W, H = 48, 36


# ---------------------------------------------------------------- de Boor


def test_de_boor_matches_hand_computed_values() -> None:
    # Uniform cubic, knots 0..7, one domain span [3, 4]. At its middle the basis functions are
    # (1/48, 23/48, 23/48, 1/48): with control points 1, 2, 4, 8 -> (1 + 46 + 92 + 8) / 48 = 3.0625.
    assert evaluate(np.arange(8.0), [1.0, 2.0, 4.0, 8.0], 3, [3.5])[0, 0] == pytest.approx(3.0625, abs=1e-15)
    # At the domain start: (P0 + 4 P1 + P2) / 6 = (1 + 8 + 4) / 6.
    assert evaluate(np.arange(8.0), [1.0, 2.0, 4.0, 8.0], 3, [3.0])[0, 0] == pytest.approx(13 / 6, abs=1e-15)
    # Clamped quadratic (a Bezier curve): (1-u)^2 * 1 + 2u(1-u) * 5 + u^2 * 2 at u = 0.25 -> 2.5625.
    assert evaluate([0, 0, 0, 1, 1, 1], [1.0, 5.0, 2.0], 2, [0.25])[0, 0] == pytest.approx(2.5625, abs=1e-15)
    # Degree 1 on non-uniform knots is linear interpolation: halfway through [1, 3] between 10 and 4 -> 7.
    assert evaluate([0, 0, 1, 3, 3], [0.0, 10.0, 4.0], 1, [2.0])[0, 0] == pytest.approx(7.0, abs=1e-15)
    # The right end of a clamped spline is its last control point.
    assert evaluate([0, 0, 0, 1, 1, 1], [1.0, 5.0, 2.0], 2, [1.0])[0, 0] == 2.0


def test_batched_de_boor_equals_scipy_on_random_splines() -> None:
    rng = np.random.default_rng(4)
    for degree in (1, 2, 3, 5):
        counts = rng.integers(degree + 1, 30, size=12)
        max_n = int(counts.max())
        knots = np.zeros((12, max_n + degree + 1 + 3))
        ctrl = np.zeros((12, max_n + 2, 3))
        u = np.zeros((12, 25))
        splines = []
        for b, n in enumerate(counts):
            k = np.sort(rng.uniform(-2, 5, size=n + degree + 1))
            k[degree + 2] = k[degree + 1]  # a repeated interior knot
            knots[b, : len(k)] = k
            knots[b, len(k) :] = 1e9  # padding must be ignored
            ctrl[b, :n] = rng.normal(size=(n, 3))
            lo, hi = k[degree], k[n]
            u[b] = np.concatenate([[lo, hi], rng.uniform(lo, hi, size=23)])
            splines.append(scipy.interpolate.BSpline(k, ctrl[b, :n], degree, extrapolate=False))
        got = de_boor(knots, ctrl, counts, degree, u)
        for b, spline in enumerate(splines):
            want = spline(u[b])
            # At the right end of the domain the spline is its limit from the left; scipy returns NaN or,
            # with a repeated end knot, 0 there, so the reference is taken one ulp inside.
            want[1] = spline(np.nextafter(u[b][1], -np.inf))
            np.testing.assert_allclose(got[b], want, rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- resampling


def make_records(n: int, num_ctrl: int, order: int = 3) -> np.ndarray:
    records = np.zeros(n, dtype=record_dtype(W, H, 136, 128, 128))
    records["bspline_order"] = order
    records["num_ctrl_pts"] = num_ctrl
    records["num_knots"] = num_ctrl + order + 1
    records["q_world_body"] = [0.0, 0.0, 0.0, 1.0]
    return records


def test_a_uniform_cubic_over_the_horizon_is_recovered_exactly() -> None:
    cfg = ResampleConfig()
    rng = np.random.default_rng(1)
    k = cfg.num_ctrl_pts
    records = make_records(3, num_ctrl=k + 6)  # longer than the horizon: only its first K points matter there
    for r in records:
        r["knots"][: k + 10] = uniform_knots(k + 6, 3, cfg.knot_dt_s) + 7.0  # any knot origin
        r["ctrl_pts_world"][: k + 6] = rng.normal(size=(k + 6, 3)) * 3
        r["depth_stamp_s"] = 100.25
        r["bspline_start_time_s"] = 100.25  # u = knots[3] is flown at the depth stamp
    arrays = records_to_arrays(records)
    want = records["ctrl_pts_world"][:, :k].astype(np.float32)
    np.testing.assert_allclose(arrays.bspline_ctrl_world, want, atol=2e-6)
    assert float(arrays.fit_rms_m.max()) < 1e-9


def test_the_expert_spline_is_held_at_its_ends() -> None:
    cfg = ResampleConfig()
    s = cfg.sample_times_s
    records = make_records(1, num_ctrl=5)
    knots = uniform_knots(5, 3, 0.25)  # domain [0, 0.5] s
    records["knots"][0, :9] = knots
    records["ctrl_pts_world"][0, :5] = np.arange(15.0).reshape(5, 3) ** 1.5
    records["depth_stamp_s"] = 10.0
    records["bspline_start_time_s"] = 10.2  # the plan starts 0.2 s after the observation
    y = expert_samples(records, s)[0]
    spline_start = evaluate(knots, records["ctrl_pts_world"][0, :5], 3, [0.0])[0]
    spline_end = evaluate(knots, records["ctrl_pts_world"][0, :5], 3, [0.5])[0]
    np.testing.assert_allclose(y[s <= 0.2], np.broadcast_to(spline_start, y[s <= 0.2].shape), atol=1e-12)
    np.testing.assert_allclose(y[s >= 0.7], np.broadcast_to(spline_end, y[s >= 0.7].shape), atol=1e-12)
    inside = (s > 0.2) & (s < 0.7)
    np.testing.assert_allclose(
        y[inside], evaluate(knots, records["ctrl_pts_world"][0, :5], 3, s[inside] - 0.2)
    )


def test_local_frame_is_the_yaw_only_vehicle_frame() -> None:
    yaw = np.array([0.3, -2.0])
    q = np.stack([np.zeros(2), np.zeros(2), np.sin(yaw / 2), np.cos(yaw / 2)], axis=-1)
    np.testing.assert_allclose(yaw_from_quaternion_xyzw(q), yaw)
    # The heading of a tilted attitude is its ZYX yaw: roll and pitch do not change it.
    tilted = Rotation.from_euler("ZYX", [0.7, 0.2, -0.15]).as_quat()  # x, y, z, w
    assert yaw_from_quaternion_xyzw(tilted) == pytest.approx(0.7, abs=1e-12)
    p = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, 1.0]])
    pts = np.array([[[2.0, 2.0, 3.0]], [[-4.0, 1.5, 2.0]]])
    local = world_to_local(pts, p, yaw)
    for i in range(2):
        c, s = np.cos(yaw[i]), np.sin(yaw[i])
        r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        np.testing.assert_allclose(local[i, 0], r.T @ (pts[i, 0] - p[i]), atol=1e-15)
    np.testing.assert_allclose(local_to_world(local, p, yaw), pts, atol=1e-14)


# ---------------------------------------------------------------- npz vs shards


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pp") / "ds"
    return write_synthetic_dataset(
        out, seed=8, records=45, width=W, height=H, records_per_episode=15, shard_size_mb=0.1
    )


@pytest.fixture(scope="module")
def npz(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pp") / "out.npz"
    subprocess.run([sys.executable, str(SCRIPT), str(dataset), str(out), "--quiet"], check=True)
    return out


def scipy_resample(rec: np.void, cfg: ResampleConfig) -> np.ndarray:
    """The documented resampling, written independently with scipy."""
    p, n = int(rec["bspline_order"]), int(rec["num_ctrl_pts"])
    knots = rec["knots"][: n + p + 1]
    spline = scipy.interpolate.BSpline(knots, rec["ctrl_pts_world"][:n], p)
    s = cfg.sample_times_s
    u = np.clip(knots[p] + (rec["depth_stamp_s"] - rec["bspline_start_time_s"]) + s, knots[p], knots[n])
    y = spline(u)
    tau = (np.arange(cfg.num_ctrl_pts + 4) - 3) * cfg.horizon_s / (cfg.num_ctrl_pts - 3)
    a = scipy.interpolate.BSpline.design_matrix(s, tau, 3).toarray()
    return scipy.linalg.lstsq(a, y)[0]


def test_npz_equals_the_shards_after_the_documented_resampling(dataset: Path, npz: Path) -> None:
    arrays = FixedSizeArrays.load(npz)
    loaded = load_dataset(dataset)
    rec = loaded.records
    assert len(arrays) == len(rec) == 45
    assert len(open_dataset(dataset).shards) >= 3
    # Bit-identical to the library function training uses on shards.
    assert arrays.equals(records_to_arrays(loaded))
    # The same numbers from an independent scipy implementation of the documented procedure.
    cfg = ResampleConfig(num_ctrl_pts=arrays.num_ctrl_pts, horizon_s=arrays.horizon_s)
    for i in range(len(rec)):
        want = scipy_resample(rec[i], cfg)
        np.testing.assert_allclose(arrays.bspline_ctrl_world[i], want, rtol=0, atol=5e-5)
        yaw = np.arctan2(
            2
            * (
                rec["q_world_body"][i, 3] * rec["q_world_body"][i, 2]
                + rec["q_world_body"][i, 0] * rec["q_world_body"][i, 1]
            ),
            1 - 2 * (rec["q_world_body"][i, 1] ** 2 + rec["q_world_body"][i, 2] ** 2),
        )
        c, s = np.cos(yaw), np.sin(yaw)
        local = (want - rec["p_world_body"][i]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        np.testing.assert_allclose(arrays.bspline_ctrl_local[i], local, rtol=0, atol=5e-5)
    # Every other array is the shard field, converted as documented.
    codes = rec["depth_code"]
    expected_depth = (codes / 1000.0).astype(np.float16)
    expected_depth[codes == 0] = np.nan
    expected_depth[codes == 1] = -np.inf
    expected_depth[codes == 65535] = np.inf
    assert arrays.depth_m.tobytes() == expected_depth.tobytes()
    assert np.isposinf(arrays.depth_m).any()
    for name in ("episode_id", "world_seed", "sim_time_s", "depth_stamp_s", "odom_stamp_s"):
        np.testing.assert_array_equal(getattr(arrays, name), rec[name])
    for name in ("p_world_body", "v_world", "q_world_body", "w_body", "goal_world"):
        np.testing.assert_array_equal(getattr(arrays, name), rec[name].astype(np.float32))
    np.testing.assert_array_equal(arrays.record_seq, rec["seq"])


def test_npz_follows_the_contract(npz: Path) -> None:
    with np.load(npz) as data:
        n = data["episode_id"].shape[0]
        k = int(data["num_ctrl_pts"])
        assert k == 10 and float(data["horizon_s"]) == 2.0 and int(data["format_version"]) == 1
        contract = {
            "depth_m": (np.float16, (n, H, W)),
            "episode_id": (np.int64, (n,)),
            "world_seed": (np.uint64, (n,)),
            "sim_time_s": (np.float64, (n,)),
            "depth_stamp_s": (np.float64, (n,)),
            "odom_stamp_s": (np.float64, (n,)),
            "p_world_body": (np.float32, (n, 3)),
            "v_world": (np.float32, (n, 3)),
            "q_world_body": (np.float32, (n, 4)),
            "w_body": (np.float32, (n, 3)),
            "goal_world": (np.float32, (n, 3)),
            "bspline_ctrl_world": (np.float32, (n, k, 3)),
            "bspline_ctrl_local": (np.float32, (n, k, 3)),
        }
        for name, (dtype, shape) in contract.items():
            assert data[name].dtype == dtype and data[name].shape == shape, name
        assert set(data.files) == set(NPZ_ARRAYS) | {"num_ctrl_pts", "horizon_s", "format_version"}


def test_training_can_resample_straight_from_a_shard_map(dataset: Path, npz: Path) -> None:
    shard = open_dataset(dataset).shards[1]
    arrays = FixedSizeArrays.load(npz)
    direct = records_to_arrays(shard.records[2:5])
    offset = open_dataset(dataset).shards[0].num_records
    np.testing.assert_array_equal(
        direct.bspline_ctrl_local, arrays.bspline_ctrl_local[offset + 2 : offset + 5]
    )
    np.testing.assert_array_equal(direct.depth_m, arrays.depth_m[offset + 2 : offset + 5])
    one = records_to_arrays(open_dataset(dataset)[offset + 3])  # a single record
    assert len(one) == 1
    np.testing.assert_array_equal(one.bspline_ctrl_world[0], arrays.bspline_ctrl_world[offset + 3])


def test_other_horizon_and_control_point_count(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "k6.npz"
    subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            str(dataset),
            str(out),
            "--num-ctrl-pts",
            "6",
            "--horizon-s",
            "1.5",
            "--quiet",
        ],
        check=True,
    )
    arrays = FixedSizeArrays.load(out)
    assert arrays.bspline_ctrl_world.shape == (45, 6, 3) and arrays.horizon_s == 1.5
    assert arrays.equals(records_to_arrays(load_dataset(dataset), num_ctrl_pts=6, horizon_s=1.5))


# ---------------------------------------------------------------- errors


def run_script(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args, "--quiet"], capture_output=True, text=True, check=False
    )


def test_bad_paths_empty_and_foreign_directories_give_clear_errors(dataset: Path, tmp_path: Path) -> None:
    out = str(tmp_path / "o.npz")
    r = run_script(str(tmp_path / "missing"), out)
    assert r.returncode == 1 and "missing: no such dataset directory" in r.stderr
    (tmp_path / "empty").mkdir()
    r = run_script(str(tmp_path / "empty"), out)
    assert r.returncode == 1 and "empty: empty directory, not a quad_il dataset" in r.stderr
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "images.txt").write_text("hello")
    r = run_script(str(tmp_path / "foreign"), out)
    assert (
        r.returncode == 1 and "not a quad_il dataset (no manifest.yaml and no shard_*.qdr files)" in r.stderr
    )
    r = run_script(str(dataset), str(tmp_path / "o.npy"))
    assert r.returncode == 1 and "output file name must end in .npz" in r.stderr
    r = run_script(str(dataset), str(tmp_path / "nodir" / "o.npz"))
    assert r.returncode == 1 and "output directory does not exist" in r.stderr
    r = run_script(str(dataset), out, "--num-ctrl-pts", "3")
    assert r.returncode == 1 and "num_ctrl_pts" in r.stderr
    assert not Path(out).exists()


def test_loading_a_foreign_or_other_version_npz_fails_clearly(npz: Path, tmp_path: Path) -> None:
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.zeros(3))
    with pytest.raises(DatasetError, match="not a quad_il training npz"):
        FixedSizeArrays.load(foreign)
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["format_version"] = np.asarray(2)
    other = tmp_path / "v2.npz"
    np.savez(other, **arrays)
    with pytest.raises(FormatVersionError, match="npz format version 2 is not supported"):
        FixedSizeArrays.load(other)
    with pytest.raises(DatasetError, match="no such npz file"):
        FixedSizeArrays.load(tmp_path / "nope.npz")
    arrays["format_version"] = np.asarray(1)
    arrays["bspline_ctrl_local"] = arrays["bspline_ctrl_local"][:, :5]
    broken = tmp_path / "broken.npz"
    np.savez(broken, **arrays)
    with pytest.raises(ValueError, match=r"bspline_ctrl_local: expected float32 \(45, 10, 3\)"):
        FixedSizeArrays.load(broken)

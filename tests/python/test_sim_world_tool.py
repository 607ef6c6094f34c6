"""quad_sim's world generator and world files, checked from Python with independent numpy geometry.

Runs the `quad_sim_world` tool of the built workspace (skipped when quad_sim is not built and sourced).
"""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SIM_YAML = ROOT / "config" / "sim.yaml"


def find_tool() -> Path | None:
    for prefix in os.environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep):
        candidate = Path(prefix) / "lib" / "quad_sim" / "quad_sim_world"
        if prefix and candidate.is_file():
            return candidate
    return None


TOOL = find_tool()
pytestmark = pytest.mark.skipif(TOOL is None, reason="quad_sim_world is not built (source devel/setup.bash)")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(TOOL), *args], capture_output=True, text=True, timeout=120)


def generate(tmp_path: Path, seed: int, *extra: str) -> Path:
    out = tmp_path / f"world_{seed}_{len(extra)}.yaml"
    res = run("generate", "--config", str(SIM_YAML), "--seed", str(seed), "--out", str(out), *extra)
    assert res.returncode == 0, res.stderr
    return out


def rotation_xyzw(q: list[float]) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def point_box_distance(p: np.ndarray, box: dict) -> float:
    local = rotation_xyzw(box["q_xyzw"]).T @ (p - np.array(box["center_m"]))
    outside = np.maximum(np.abs(local) - 0.5 * np.array(box["size_m"]), 0.0)
    return float(np.linalg.norm(outside))


def test_same_seed_gives_byte_identical_world_files(tmp_path: Path) -> None:
    a = generate(tmp_path, 11).read_bytes()
    b = generate(tmp_path, 11).read_bytes()
    c = generate(tmp_path, 12).read_bytes()
    assert a == b
    assert a != c


def test_world_file_format_and_default_density(tmp_path: Path) -> None:
    world = yaml.safe_load(generate(tmp_path, 3).read_text())
    assert world["format"] == "quad_sim_world"
    assert world["version"] == 1
    assert world["seed"] == 3
    assert np.allclose(np.subtract(world["bounds_max_m"], world["bounds_min_m"]), [40, 40, 5])
    assert len(world["boxes"]) == 200
    for box in world["boxes"]:
        assert set(box) == {"center_m", "q_xyzw", "size_m"}
        assert abs(np.linalg.norm(box["q_xyzw"]) - 1.0) < 1e-12
        assert min(box["size_m"]) > 0


def test_clear_zones_around_start_and_goal_are_respected(tmp_path: Path) -> None:
    cfg = yaml.safe_load(SIM_YAML.read_text())
    radius = cfg["world"]["generator"]["clear_radius_m"]
    start, goal = np.array([-5.0, 4.0, 1.0]), np.array([7.0, -3.0, 2.0])
    path = generate(tmp_path, 8, "--start", "-5,4,1", "--goal", "7,-3,2")
    boxes = yaml.safe_load(path.read_text())["boxes"]
    distances = [min(point_box_distance(start, b), point_box_distance(goal, b)) for b in boxes]
    assert min(distances) > radius
    # The zones are not trivially empty: some box comes within a metre of the zone boundary.
    assert min(distances) < radius + 1.0


def test_check_names_an_unknown_key(tmp_path: Path) -> None:
    path = generate(tmp_path, 4)
    text = path.read_text().replace("size_m:", "colour: red, size_m:", 1)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    res = run("check", "--world", str(bad))
    assert res.returncode == 1
    assert "boxes[0]: unknown config key(s): 'colour'" in res.stderr


def count_overlapping_voxels(boxes: list[dict], lo: np.ndarray, hi: np.ndarray, res: float) -> int:
    """Voxels of the grid aligned at multiples of `res` whose cube overlaps any box (separating-axis test)."""
    idx_lo, idx_hi = np.floor(lo / res).astype(int), np.ceil(hi / res).astype(int)
    axes = [np.arange(a, b) for a, b in zip(idx_lo, idx_hi, strict=True)]
    centres = (np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3) + 0.5) * res
    occupied = np.zeros(len(centres), dtype=bool)
    half_voxel = 0.5 * res
    for box in boxes:
        rot, half = rotation_xyzw(box["q_xyzw"]), 0.5 * np.array(box["size_m"])
        t = np.array(box["center_m"]) - centres
        candidates = [np.eye(3)[k] for k in range(3)] + [rot[:, j] for j in range(3)]
        candidates += [np.cross(np.eye(3)[k], rot[:, j]) for k in range(3) for j in range(3)]
        separated = np.zeros(len(centres), dtype=bool)
        for axis in candidates:
            reach = half_voxel * np.abs(axis).sum() + (half * np.abs(rot.T @ axis)).sum()
            separated |= np.abs(t @ axis) > reach + 1e-12
        occupied |= ~separated
    return int(occupied.sum())


def test_voxelize_writes_an_octomap_file_with_the_exact_occupancy(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    boxes = []
    for _ in range(6):
        q = rng.normal(size=4)
        boxes.append(
            {
                "center_m": rng.uniform([-2.0, -2.0, 0.5], [2.0, 2.0, 2.5]).round(6).tolist(),
                "q_xyzw": (q / np.linalg.norm(q)).tolist(),
                "size_m": rng.uniform(0.2, 1.2, size=3).round(6).tolist(),
            }
        )
    world = {
        "format": "quad_sim_world",
        "version": 1,
        "seed": 0,
        "bounds_min_m": [-3.0, -3.0, 0.0],
        "bounds_max_m": [3.0, 3.0, 3.0],
        "boxes": boxes,
    }
    path = tmp_path / "random.yaml"
    path.write_text(yaml.safe_dump(world))
    out = tmp_path / "map.bt"
    res = run("voxelize", "--config", str(SIM_YAML), "--world", str(path), "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert out.read_bytes().startswith(b"# Octomap OcTree binary file")
    occupied = int(res.stdout.split("boxes: ")[1].split(" occupied")[0])
    expected = count_overlapping_voxels(boxes, np.array([-3.0, -3.0, 0.0]), np.array([3.0, 3.0, 3.0]), 0.1)
    assert occupied == expected
    assert expected > 1000


def test_usage_errors_exit_2() -> None:
    res = run("generate", "--config")
    assert res.returncode == 2
    assert "usage:" in res.stderr

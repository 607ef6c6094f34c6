"""The floor plan of the C++ packages (docs/CONVENTIONS.md, "Layers"), checked on the sources:

- no algorithm core but quad_sim names quad_sim in its CMakeLists.txt or package.xml;
- a core library exports no ROS package to its users (catkin_package CATKIN_DEPENDS, package.xml <depend>);
- the shared vocabulary (vehicle state, camera intrinsics, depth image, B-spline) is defined in quad_core;
- no core package includes a harness (quad_bench) header.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src"
CORES = ["quad_sim", "kr_tracker", "fast_planner", "cpp_data_collector", "quad_policy"]
NOT_SIM = ["kr_tracker", "fast_planner", "cpp_data_collector", "quad_policy"]
ROS_PACKAGES = {"roscpp", "rospy", "actionlib", "tf2_ros", "rosgraph_msgs", "std_msgs", "nav_msgs"}
ROS_PACKAGES |= {"geometry_msgs", "sensor_msgs", "visualization_msgs", "tf2_msgs", "quad_msgs"}
VOCABULARY = {
    "VehicleState": r"struct\s+VehicleState\b",
    "CameraIntrinsics": r"struct\s+CameraIntrinsics\b",
    "DepthImage": r"struct\s+DepthImage\b",
    "DepthImageView": r"struct\s+DepthImageView\b",
    "NonUniformBspline": r"class\s+NonUniformBspline\b",
}


def _catkin_depends(cmake: str) -> set[str]:
    """The packages listed after CATKIN_DEPENDS in catkin_package(...)."""
    match = re.search(r"catkin_package\((.*?)\)", cmake, re.S)
    if not match:
        return set()
    body = match.group(1)
    deps = re.search(r"CATKIN_DEPENDS\s+(.*?)(?:\b(?:DEPENDS|INCLUDE_DIRS|LIBRARIES)\b|$)", body, re.S)
    return set(deps.group(1).split()) if deps else set()


def _names_sim(text: str) -> bool:
    return re.search(r"\bquad_sim\b", text) is not None


@pytest.mark.parametrize("pkg", NOT_SIM)
def test_cores_do_not_name_the_simulator(pkg: str) -> None:
    for name in ("CMakeLists.txt", "package.xml"):
        text = (SRC / pkg / name).read_text()
        assert not _names_sim(
            text
        ), f"src/{pkg}/{name} names quad_sim (move the code that needs it to quad_bench)"


@pytest.mark.parametrize("pkg", CORES)
def test_core_libraries_export_no_ros(pkg: str) -> None:
    exported = _catkin_depends((SRC / pkg / "CMakeLists.txt").read_text())
    assert not exported & ROS_PACKAGES, f"src/{pkg}: catkin_package exports {sorted(exported & ROS_PACKAGES)}"
    xml = (SRC / pkg / "package.xml").read_text()
    for dep in re.findall(r"<depend>([^<]+)</depend>", xml):
        assert dep not in ROS_PACKAGES, (
            f"src/{pkg}/package.xml: <depend>{dep}</depend> exports it to users of the core library "
            "(use build_depend + exec_depend for the node)"
        )


def _sources(pkg: str) -> list[Path]:
    root = SRC / pkg
    return sorted(p for p in root.rglob("*") if p.suffix in {".h", ".hpp", ".cpp"})


def test_vocabulary_is_defined_once() -> None:
    packages = sorted(p.name for p in SRC.iterdir() if (p / "package.xml").is_file())
    for name, pattern in VOCABULARY.items():
        where = [
            str(f.relative_to(ROOT))
            for pkg in packages
            for f in _sources(pkg)
            if re.search(pattern + r"\s*\{", f.read_text(errors="replace"))
        ]
        outside = [w for w in where if not w.startswith("src/quad_core/")]
        assert not outside, f"{name} is defined outside quad_core: {outside}"
        assert where, f"{name} is not defined in quad_core"


@pytest.mark.parametrize("pkg", CORES + ["quad_core"])
def test_cores_include_no_harness(pkg: str) -> None:
    for f in _sources(pkg):
        text = f.read_text(errors="replace")
        assert "quad_bench/" not in text, f"{f.relative_to(ROOT)} includes a harness header"


def test_quad_core_depends_on_no_workspace_package() -> None:
    xml = (SRC / "quad_core" / "package.xml").read_text()
    others = {p.name for p in SRC.iterdir() if (p / "package.xml").is_file()} - {"quad_core"}
    deps = set(re.findall(r"<(?:\w+_)?depend>([^<]+)</(?:\w+_)?depend>", xml))
    assert not deps & others, f"quad_core depends on {sorted(deps & others)}"


def test_checks_catch_a_violation() -> None:
    """The parsers above see what they must (so the tests can fail)."""
    cmake = "catkin_package(\n  INCLUDE_DIRS include\n  CATKIN_DEPENDS quad_core roscpp\n  DEPENDS EIGEN3)"
    assert _catkin_depends(cmake) == {"quad_core", "roscpp"}
    assert _names_sim("find_package(quad_sim REQUIRED)")
    assert not _names_sim("quad_sim_like")


def _node_files() -> list[Path]:
    """Files of ROS plumbing: C++ including ros/ros.h, Python importing rospy (outside tests)."""
    files = []
    for f in sorted(SRC.rglob("*")):
        if "test" in f.parts or not f.is_file():
            continue
        text = f.read_text(errors="replace") if f.suffix in {".cpp", ".h", ".py"} else ""
        if f.suffix in {".cpp", ".h"} and re.search(r"#include\s*[<\"]ros/ros\.h[>\"]", text):
            files.append(f)
        elif f.suffix == ".py" and re.search(r"^\s*(import rospy|from rospy\b)", text, re.M):
            files.append(f)
    return files


def test_node_files_are_at_most_350_lines() -> None:
    files = _node_files()
    assert any(f.name == "policy_node.cpp" for f in files) and any(f.name == "ros_node.py" for f in files)
    long = {str(f.relative_to(ROOT)): n for f in files if (n := len(f.read_text().splitlines())) > 350}
    assert not long, f"node files over 350 lines (move the logic into a ROS-free core module): {long}"


def test_python_inference_is_at_most_1000_lines() -> None:
    total = sum(
        len(f.read_text().splitlines()) for f in (SRC / "quad_il/src/quad_il/inference").rglob("*.py")
    )
    assert total <= 1000, f"quad_il/inference is {total} lines: the decider lives in C++ (quad_policy)"


def test_vocabulary_messages_are_converted_in_quad_ros_only() -> None:
    """Odometry, camera info and depth images <-> quad_core types: once, in quad_ros, for every node."""
    patterns = [
        r"VehicleState\s+\w+\(const nav_msgs::Odometry&",
        r"nav_msgs::Odometry\s+\w+\(const quad_core::VehicleState&",
        r"CameraIntrinsics\s+\w+\(const sensor_msgs::CameraInfo&",
        r"sensor_msgs::CameraInfo\s+\w+\(const quad_core::CameraIntrinsics&",
    ]
    packages = sorted(p.name for p in SRC.iterdir() if (p / "package.xml").is_file())
    for pattern in patterns:
        where = [
            str(f.relative_to(ROOT))
            for pkg in packages
            for f in _sources(pkg)
            if "test" not in f.parts and re.search(pattern, f.read_text(errors="replace"))
        ]
        assert where and all(w.startswith("src/quad_ros/") for w in where), f"{pattern}: {where}"

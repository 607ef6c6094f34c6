"""rviz off-screen snapshots (issue 8): rviz under Xvfb with the project's config, PNGs at chosen sim times of
a running simulation or of a recorded bag.

    python -m quad_il.evaluation.snapshot --out DIR --times 2,10.5 [--bag run.bag] [--view follow|top]
        [--voxel-map] [--trajectory planner/bspline:learned] [--trajectory expert/bspline:expert]
        [--size 1280x720] [--settle-s 3] [--max-extra-settles 5] [--timeout-s 300] [--blank]

Live (no --bag): connects to ROS_MASTER_URI (a running quad_sim, use_sim_time) and captures when the sim time
reaches each time (seconds of sim time; the simulator's clock starts at 1 s). With --bag: starts a private
roscore, plays the bag with --clock and captures at each time after the bag's start. The scene is
config/rviz/sim.rviz (world boxes, ground, goal, vehicle, TF, odometry, depth cloud and image) plus, with
--voxel-map, the simulator's voxel map, and one coloured line per --trajectory topic (quad_msgs/Bspline
sampled at 20 points per knot interval; the label picks the colour: expert blue, learned orange, others
green).
--view top replaces the vehicle-following camera by a top-down orthographic view of the world. --blank
disables every display: a reference frame of the empty scene. Writes DIR/snapshot_<time>.png (and
DIR/rviz.rviz, the config used); prints the PNG paths. Each capture waits --settle-s seconds of wall time,
then repeats (up to --max-extra-settles times) while the picture still changes, so a slowly drawing rviz on a
loaded machine is not caught half done. Exit status 0 done, 1 failure (message on stderr).

Needs Xvfb, rviz and ImageMagick's `import` (scripts/apt-packages.txt); rviz renders with Mesa's software
renderer under Xvfb (PLATFORM.md).
"""

from __future__ import annotations

import argparse
import copy
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from quad_il.evaluation.x_display import SnapshotError, capture_settled, start_xvfb, stop_process, window_up
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.ports import free_port
from quad_il.tools.repo import repo_root

ROOT = repo_root()
DEFAULT_RVIZ = ROOT / "config" / "rviz" / "sim.rviz"
TRAJECTORY_TOPIC = "snapshot/trajectories"  # relative: resolved in the namespace of the node and rviz
COLOURS = {"expert": (0.1, 0.45, 1.0), "learned": (1.0, 0.55, 0.0)}
OTHER_COLOUR = (0.2, 0.85, 0.3)


def rviz_config(
    base: dict, *, view: str, voxel_map: bool, trajectories: bool, blank: bool, size: tuple[int, int]
) -> dict:
    """The rviz config to render: `base` (config/rviz/sim.rviz) adapted to the options."""
    cfg = copy.deepcopy(base)
    manager = cfg["Visualization Manager"]
    # Image displays would take part of the window as docked panels: snapshots show the 3D scene only.
    displays = [d for d in manager["Displays"] if d.get("Class") != "rviz/Image"]
    manager["Displays"] = displays
    cfg["Panels"] = []
    for d in displays:
        if d.get("Name") == "Voxel map" and voxel_map:
            d["Enabled"] = True
            d["Value"] = True
    if trajectories:
        displays.append(
            {
                "Class": "rviz/MarkerArray",
                "Enabled": True,
                "Marker Topic": TRAJECTORY_TOPIC,
                "Name": "Trajectories",
                "Namespaces": {},
                "Queue Size": 100,
                "Value": True,
            }
        )
    if blank:
        for d in displays:
            d["Enabled"] = False
            d["Value"] = False
    if view == "top":
        manager["Views"]["Current"] = {
            "Class": "rviz/TopDownOrtho",
            "Name": "Current View",
            "Near Clip Distance": 0.01,
            "Angle": 0,
            "Scale": min(size) / 44.0,  # the 40 m world and a margin
            "Target Frame": "world",
            "X": 0,
            "Y": 0,
        }
    cfg["Window Geometry"] = {
        "Width": size[0],
        "Height": size[1],
        "X": 0,
        "Y": 0,
        "Hide Left Dock": True,
        "Hide Right Dock": True,
    }
    return cfg


class TrajectoryMarkers:
    """Bspline topics -> one LINE_STRIP marker per topic (the latest trajectory), re-published on a timer."""

    def __init__(self, specs: list[tuple[str, str]]) -> None:
        import rospy
        from visualization_msgs.msg import MarkerArray

        from quad_msgs.msg import Bspline

        self.pub = rospy.Publisher(TRAJECTORY_TOPIC, MarkerArray, queue_size=1, latch=True)
        self.latest: dict[int, tuple[str, np.ndarray]] = {}
        for i, (topic, label) in enumerate(specs):
            rospy.Subscriber(topic, Bspline, self._on_bspline, callback_args=(i, label), queue_size=5)

    def _on_bspline(self, msg, args: tuple[int, str]) -> None:
        from quad_il.data.bspline import evaluate

        i, label = args
        p = msg.order
        ctrl = np.array([[q.x, q.y, q.z] for q in msg.pos_pts])
        knots = np.asarray(msg.knots, dtype=np.float64)
        if p < 1 or len(ctrl) < p + 1 or len(knots) != len(ctrl) + p + 1 or not np.all(np.isfinite(ctrl)):
            return
        t0, t1 = knots[p], knots[len(ctrl)]
        if not t1 > t0:
            return
        pts = evaluate(knots, ctrl, p, np.linspace(t0, t1, 20 * (len(ctrl) - p) + 1))
        self.latest[i] = (label, pts)
        self.publish()

    def publish(self) -> None:
        from geometry_msgs.msg import Point
        from visualization_msgs.msg import Marker, MarkerArray

        arr = MarkerArray()
        for i, (label, pts) in self.latest.items():
            m = Marker()
            m.header.frame_id = "world"
            m.ns = label
            m.id = i
            m.type = Marker.LINE_STRIP
            m.action = Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x = 0.08
            m.color.r, m.color.g, m.color.b = COLOURS.get(label, OTHER_COLOUR)
            m.color.a = 1.0
            m.points = [Point(*map(float, q)) for q in pts]
            arr.markers.append(m)
        self.pub.publish(arr)


def take_snapshots(args: argparse.Namespace) -> list[Path]:
    for tool in ("Xvfb", "rviz", "import", "xwininfo"):
        if shutil.which(tool) is None:
            raise SnapshotError(f"{tool} not found (install the packages of scripts/apt-packages.txt)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    if len(size) != 2 or min(size) < 64:
        raise SnapshotError(f"--size must be WIDTHxHEIGHT, got {args.size!r}")
    times = sorted(float(t) for t in args.times.split(","))
    specs = []
    for s in args.trajectory:
        topic, _, label = s.partition(":")
        specs.append((topic, label or topic.strip("/").replace("/", "_")))
    base = yaml.safe_load(Path(args.rviz_config).read_text())
    cfg_path = out / "rviz.rviz"
    cfg_path.write_text(
        yaml.safe_dump(
            rviz_config(
                base,
                view=args.view,
                voxel_map=args.voxel_map,
                trajectories=bool(specs),
                blank=args.blank,
                size=size,
            ),
            sort_keys=False,
        )
    )
    procs: list[subprocess.Popen] = []
    env = dict(os.environ)
    if args.bag:
        if not Path(args.bag).is_file():
            raise SnapshotError(f"bag not found: {args.bag}")
        env["ROS_MASTER_URI"] = f"http://127.0.0.1:{free_port()}"
        os.environ["ROS_MASTER_URI"] = env["ROS_MASTER_URI"]
    xvfb = None
    paths: list[Path] = []
    try:
        if args.bag:
            port = env["ROS_MASTER_URI"].rsplit(":", 1)[1]
            procs.append(
                subprocess.Popen(
                    ["roscore", "-p", port], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
                )
            )
        import rosgraph
        import rospy

        deadline = time.monotonic() + 30.0
        while not rosgraph.is_master_online():
            if time.monotonic() > deadline:
                raise SnapshotError(f"no ROS master at {os.environ.get('ROS_MASTER_URI')}")
            time.sleep(0.2)
        if args.bag:
            rospy.set_param("/use_sim_time", True)
        else:
            # rospy reads /use_sim_time once, in init_node: give a simulator's launch file time to set it.
            master = rosgraph.Master("/rviz_snapshot_probe")
            while not master.hasParam("/use_sim_time") and time.monotonic() < deadline + 30.0:
                time.sleep(0.1)
        rospy.init_node("rviz_snapshot", anonymous=True, disable_signals=True)
        markers = TrajectoryMarkers(specs) if specs else None
        xvfb, display = start_xvfb(size)
        renv = {**env, "DISPLAY": display, "LIBGL_ALWAYS_SOFTWARE": "1"}
        procs.append(
            subprocess.Popen(
                ["rviz", "--fullscreen", "-d", str(cfg_path)],
                env=renv,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        deadline = time.monotonic() + args.timeout_s
        while not window_up(display):
            if procs[-1].poll() is not None:
                raise SnapshotError("rviz exited before showing its window")
            if time.monotonic() > deadline:
                raise SnapshotError("rviz did not show its window in time")
            time.sleep(0.2)
        t_origin = 0.0
        if args.bag:
            procs.append(
                subprocess.Popen(
                    ["rosbag", "play", "--clock", "-q", args.bag],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
            while rospy.Time.now().is_zero():
                if time.monotonic() > deadline:
                    raise SnapshotError("the bag's clock did not start")
                time.sleep(0.05)
            t_origin = rospy.Time.now().to_sec()
        for t in times:
            while rospy.Time.now().to_sec() - t_origin < t:
                if time.monotonic() > deadline:
                    raise SnapshotError(f"sim time {t} s not reached within --timeout-s {args.timeout_s}")
                time.sleep(0.02)
            if markers is not None:
                markers.publish()
            time.sleep(args.settle_s)  # wall time: rviz draws at about 10 frames/s under Xvfb
            png = out / f"snapshot_{t:g}.png"
            capture_settled(display, png, args.settle_s, args.max_extra_settles)
            paths.append(png)
            print(png, flush=True)
    finally:
        for p in reversed(procs):
            stop_process(p)
        stop_process(xvfb, signal.SIGTERM)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument(
        "--times", required=True, help="comma-separated sim times (s); with --bag: after its start"
    )
    ap.add_argument("--bag", default=None, help="replay this bag instead of a running simulator")
    ap.add_argument("--rviz-config", default=str(DEFAULT_RVIZ), help="rviz display config")
    ap.add_argument(
        "--view", choices=["follow", "top"], default="follow", help="camera: behind the vehicle or top-down"
    )
    ap.add_argument("--voxel-map", action="store_true", help="show the simulator's voxel map")
    ap.add_argument("--trajectory", action="append", default=[], help="TOPIC[:LABEL] of quad_msgs/Bspline")
    ap.add_argument("--size", default="1280x720", help="image size WxH (px)")
    ap.add_argument("--settle-s", type=float, default=3.0, help="wall time rviz draws before a capture")
    ap.add_argument(
        "--max-extra-settles",
        type=int,
        default=5,
        help="further captures while the picture still changes (a loaded machine draws slowly)",
    )
    ap.add_argument("--timeout-s", type=float, default=300.0, help="wall-time limit of the whole command")
    ap.add_argument("--blank", action="store_true", help="every display off: the empty scene (a reference)")
    args = ap.parse_args(argv)
    try:
        take_snapshots(args)
    except (SnapshotError, subprocess.CalledProcessError, OSError, yaml.YAMLError) as e:
        print(f"snapshot: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""No Python file outside tests writes a global topic, service or parameter name (issue 31): a node pushed
into a namespace must talk to that namespace's simulator. Allowed: ROS's own /clock, /tf, /tf_static, /rosout
and the /use_sim_time parameter; the caller id of a rosgraph.Master is not a topic.

Two checks on the syntax tree of every Python file of the repository outside tests/:
1. the name argument of rospy/actionlib calls (Subscriber, Publisher, ServiceProxy, wait_for_service,
   get_param, ActionClient, ...) must not be a literal starting with '/' other than the allowed ones;
2. no other string literal (or f-string head) may be a global name of the project's topic vocabulary (the
   first segment of docs/CONVENTIONS.md's topics: /odom, /sim/..., /planner/..., ...), e.g. a constant that
   is passed to a Subscriber later.
"""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ALLOWED = {"/clock", "/tf", "/tf_static", "/rosout", "/use_sim_time"}
ROS_CALLS = {
    "Subscriber",
    "Publisher",
    "ServiceProxy",
    "Service",
    "wait_for_service",
    "wait_for_message",
    "get_param",
    "set_param",
    "has_param",
    "delete_param",
    "search_param",
    "ActionClient",
    "SimpleActionClient",
    "ActionServer",
    "SimpleActionServer",
    "require_param",
}
VOCABULARY = {
    "odom",
    "camera",
    "sim",
    "planner",
    "tracker",
    "policy",
    "so3_cmd",
    "trpy_cmd",
    "position_cmd",
    "expert",
    "expert_a",
    "expert_b",
    "learner",
    "snapshot",
    "imitation_collector",
    "episode_manager",
}
GLOBAL_NAME = re.compile(r"^/(?P<head>[A-Za-z_][A-Za-z0-9_]*)(/[A-Za-z0-9_/]*)?(:.*)?$")


def python_files() -> list[Path]:
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.py"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    return sorted(ROOT / f for f in set(out) if not f.startswith("tests/") and (ROOT / f).is_file())


def _call_name(node: ast.Call) -> str:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


def _docstrings(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                ids.add(id(body[0].value))
    return ids


def global_names(source: str, filename: str = "<src>") -> list[tuple[int, str]]:
    """(line, literal) of every global topic/service/parameter name the source writes."""
    tree = ast.parse(source, filename)
    found: dict[tuple[int, str], None] = {}
    skip = _docstrings(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            name = _call_name(node)
            if name == "Master":  # rosgraph.Master(caller_id): a caller id, not a topic
                skip.update(id(a) for a in node.args[:1])
                continue
            if name in ROS_CALLS:
                args = list(node.args[:1]) + [k.value for k in node.keywords if k.arg in ("name", "topic")]
                for a in args:
                    if isinstance(a, ast.Constant) and isinstance(a.value, str):
                        skip.add(id(a))
                        if a.value.startswith("/") and a.value not in ALLOWED:
                            found[(a.lineno, a.value)] = None
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr) and node.values and isinstance(node.values[0], ast.Constant):
            skip.add(id(node.values[0]))
            text = str(node.values[0].value)
            m = GLOBAL_NAME.match(text.split("{")[0] + ("x" if text.endswith("/") else ""))
            if m and m["head"] in VOCABULARY:
                found[(node.lineno, text)] = None
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            m = GLOBAL_NAME.match(node.value)
            if m and m["head"] in VOCABULARY and node.value not in ALLOWED:
                found[(node.lineno, node.value)] = None
    return sorted(found)


def test_the_checker_finds_global_names_and_accepts_the_allowed_ones() -> None:
    src = '''
"""Docstring mentioning /odom is prose."""
import rospy, rosgraph
STATUS = {"expert": "/planner/status"}
rospy.Subscriber("/odom", Odometry, cb)
rospy.Publisher("sim/frame_ack", FrameAck)
rospy.Publisher("/clock", Clock)
rospy.get_param("/use_sim_time")
rospy.get_param("/some/global")
rosgraph.Master("/probe")
rospy.ServiceProxy(name="/tracker/goto", service_class=Goto)
topic = f"/planner/bspline:{label}"
path = "/tmp/out"
'''
    assert global_names(src) == [
        (4, "/planner/status"),
        (5, "/odom"),
        (9, "/some/global"),
        (11, "/tracker/goto"),
        (12, "/planner/bspline:"),
    ]


def test_no_python_file_outside_tests_writes_a_global_topic_name() -> None:
    files = python_files()
    assert any(f.name == "ros_collector.py" for f in files) and len(files) > 50
    bad = []
    for f in files:
        for line, text in global_names(f.read_text(), str(f)):
            bad.append(f"{f.relative_to(ROOT)}:{line}: {text!r}")
    assert not bad, "global names (make them relative, docs/CONVENTIONS.md):\n" + "\n".join(bad)

"""The ROS-free pieces the rospy collector and episode manager are built from: the frame/odometry
pairing rule, required parameters, the collector's acknowledgement book, odometry buffer, held frames and
its node config."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from quad_il.frame_pairing import in_control_period, newest_at_or_before, period_arrived
from quad_il.imitation.collector_config import KEYS, load_collector_node_config
from quad_il.imitation.collector_core import AckBook, CollectorCounters, HeldFrames, OdometryBuffer
from quad_il.imitation.types import ImitationError
from quad_il.ros_params import MissingParameterError, require_param

ROOT = Path(__file__).resolve().parents[2]
PERIOD = 0.005


def test_the_pairing_rule_is_stamp_after_t_minus_period_and_at_most_t() -> None:
    t = 1.0
    assert in_control_period(1.0, t, PERIOD)  # the frame's own control period
    assert in_control_period(0.996, t, PERIOD)
    assert not in_control_period(0.995, t, PERIOD)  # exactly one period before: the previous period
    assert not in_control_period(1.001, t, PERIOD)  # after the frame
    assert period_arrived(1.001, t, PERIOD) and not period_arrived(0.995, t, PERIOD)
    stamps = [0.985, 0.99, 0.995, 1.0, 1.005]
    assert newest_at_or_before(stamps, 1.0) == 3
    assert newest_at_or_before(stamps, 0.9975) == 2
    assert newest_at_or_before(stamps, 0.5) == -1 and newest_at_or_before([], 1.0) == -1


class FakeParams:
    def __init__(self, values: dict[str, object]) -> None:
        self.values = values

    def has_param(self, name: str) -> bool:
        return name in self.values

    def get_param(self, name: str) -> object:
        return self.values[name]

    def resolve_name(self, name: str) -> str:
        return "/ns/node/" + name[1:] if name.startswith("~") else "/ns/" + name


def test_a_missing_parameter_is_an_error_naming_it_and_where_to_set_it() -> None:
    params = FakeParams({"~odom_period_s": 0.005, "~lockstep": False})
    assert require_param("~odom_period_s", "launch/x.launch", params) == 0.005
    assert require_param("~lockstep", "launch/x.launch", params) is False  # a falsy value is a value
    with pytest.raises(MissingParameterError) as err:
        require_param("~tracker_node", "launch/collect.launch", params)
    assert str(err.value) == (
        "missing parameter '~tracker_node' (resolved: /ns/node/tracker_node; set it in launch/collect.launch)"
    )


def test_acknowledgements_are_kept_per_source_and_trimmed_oldest_first() -> None:
    book = AckBook(["expert", "learner"], keep=4)
    book.add("expert", 0.1)
    assert book.acked("expert", 0.1) and not book.acked("learner", 0.1) and book.any_acked(0.1)
    assert book.acked("expert", 0.1 + 1e-12)  # the same nanosecond stamp
    for i in range(2, 6):
        book.add("expert", 0.1 * i)
    assert not book.acked("expert", 0.1) and not book.acked("expert", 0.2)  # 5 > 4: the oldest 2 dropped
    assert book.acked("expert", 0.5)


def odom(t: float) -> SimpleNamespace:
    return SimpleNamespace(stamp=t)


def test_the_odometry_buffer_pairs_the_newest_at_or_before_the_frame() -> None:
    counters = CollectorCounters()
    buf = OdometryBuffer[SimpleNamespace](PERIOD, 0.0, counters, keep=3)
    assert buf.for_frame(1.0) is None
    for t in (0.99, 0.995, 1.0, 1.005):
        buf.add(t, odom(t))
    used, latest = buf.for_frame(1.0)
    assert (used.stamp, latest.stamp) == (1.0, 1.005)
    assert buf.for_frame(0.99) is None  # 0.99 fell out of the 3 kept: nothing at or before it
    buf.add(0.2, odom(0.2))  # time went back (a new run): the buffer starts afresh
    used, latest = buf.for_frame(1.0)
    assert used.stamp == 0.2 and latest.stamp == 0.2
    assert counters.odom_waits == 0  # wait_s 0: never waits


def test_the_odometry_buffer_waits_for_the_frames_control_period() -> None:
    counters = CollectorCounters()
    buf = OdometryBuffer[SimpleNamespace](PERIOD, 5.0, counters)
    buf.add(0.99, odom(0.99))
    started = threading.Event()

    def late() -> None:
        started.wait()
        buf.add(0.995, odom(0.995))  # still the previous period: not enough
        buf.add(1.0, odom(1.0))

    th = threading.Thread(target=late)
    th.start()
    started.set()
    used, _ = buf.for_frame(1.0)
    th.join()
    assert used.stamp == 1.0 and counters.odom_waits == 1 and counters.odom_wait_timeouts == 0
    short = OdometryBuffer[SimpleNamespace](PERIOD, 0.01, counters)
    short.add(0.9, odom(0.9))
    used, _ = short.for_frame(1.0)  # the frame's odometry never comes: the newest older one, counted
    assert used.stamp == 0.9 and counters.odom_wait_timeouts == 1


def test_held_frames_expire_after_the_pair_timeout_oldest_first() -> None:
    now = [0.0]
    held = HeldFrames(5.0, lambda: now[0])
    held.hold(2.0)
    now[0] = 1.0
    held.hold(1.0)
    held.hold(3.0)
    held.release(3.0)
    now[0] = 5.5
    assert held.expired() == [2.0]
    now[0] = 6.5
    assert held.expired() == [1.0] and held.expired() == []


def test_the_shipped_collector_config_loads_and_private_parameters_override_it(tmp_path: Path) -> None:
    path = ROOT / "config" / "imitation_collector.yaml"
    cfg = load_collector_node_config(path, {})
    assert cfg.expert_topics == {"expert": "expert/bspline"} and cfg.odom_period_s == 0.005
    assert cfg.consumer_name == "imitation_collector" and cfg.ack_grace_s == 0.25
    mega = load_collector_node_config(path, {"expert_topics": {"expert_a": "a/bspline"}})
    assert mega.expert_topics == {"expert_a": "a/bspline"} and mega.learner_topic == "learner/bspline"
    text = path.read_text()
    missing = tmp_path / "missing.yaml"
    missing.write_text("\n".join(line for line in text.splitlines() if not line.startswith("odom_wait_s")))
    with pytest.raises(ImitationError, match=r"missing.yaml: 'odom_wait_s': Field required"):
        load_collector_node_config(missing, {})
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text(text + "\nack_grace: 1.0\n")
    with pytest.raises(ImitationError, match=r"'ack_grace': Extra inputs are not permitted"):
        load_collector_node_config(unknown, {})
    with pytest.raises(ImitationError, match=r"'pair_timeout_s': Input should be greater than 0"):
        load_collector_node_config(path, {"pair_timeout_s": 0})
    assert "timing_log" in KEYS and len(KEYS) == 12

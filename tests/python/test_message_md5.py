"""The message package keeps wire compatibility with Fast-Planner and kr_mav_msgs (same MD5 sums)."""

import subprocess

import pytest

EXPECTED = {
    "Bspline": "b352d4f7278a546180de67cbe6793e49",
    "SO3Command": "6778903d02fc8f91a4ade288d0a1f3d6",
    "TRPYCommand": "f80239b313b23c6da7a6269aae03beb6",
    "PositionCommand": "0311a8eaed8b83c776def91b77632ae6",
    "AuxCommand": "94f75840e4b1e03675da764692f2c839",
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_rospy_message_md5_matches_upstream(name):
    import quad_msgs.msg

    assert getattr(quad_msgs.msg, name)._md5sum == EXPECTED[name]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_rosmsg_md5_command_prints_upstream_sum(name):
    out = subprocess.run(["rosmsg", "md5", f"quad_msgs/{name}"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == EXPECTED[name]


def test_track_bspline_action_carries_a_bspline_goal():
    from quad_msgs.msg import TrackBsplineFeedback, TrackBsplineGoal, TrackBsplineResult

    assert TrackBsplineGoal().bspline._type == "quad_msgs/Bspline"
    result = TrackBsplineResult()
    assert {"success", "total_time_s", "distance_travelled_m", "reason"} <= set(result.__slots__)
    assert "remaining_time_s" in TrackBsplineFeedback.__slots__

"""The simulator's frames as a lockstep depth consumer sees them (rospy): shared by the collection's episode
manager and the closed-loop evaluation's episode runner.

A node that takes decisions (take-off, goal, end of episode) at depth frames names itself in the simulator's
`lockstep.depth_consumers`. The simulator then publishes nothing newer than a frame until every consumer has
acknowledged it (FrameAck, cumulative by stamp). `FrameGate.next_frame` returns the next frame and holds it;
the node acts on it and releases it with `ack`. What the node does at a frame therefore happens at the same
sim time in every run, whatever the machine's load. Without lockstep (a free-running simulator) the same calls
just return the newest frame and acknowledge nothing.

Start-up: the simulator starts stepping once every consumer's FrameAck publisher delivers to it and every
topic a consumer has registered for (its frames, odometry, clock) is connected (quad_core/lockstep_gate.h,
issue 30), so a consumer normally gets the episode's first frame. The node still takes no decision in the
first STARTUP_ACK_S of sim time after the simulator's first status and acknowledges that stretch blindly
(cumulative acknowledgements) if no frame arrives, e.g. beside a simulator that was already stepping; the
first frame it holds comes after it, in every run.

Every lockstep wait of the simulator that ends by timeout is counted in its SimStats (published before every
depth frame in lockstep): a consumer holding a frame can read the counts up to it (the evaluation's runner
records them per episode, EpisodeResult.lockstep_timeouts).
"""

from __future__ import annotations

import bisect
import math
import queue
import threading
import time
from collections.abc import Callable

import rospy
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import String

from quad_il.frame_pairing import newest_at_or_before, period_arrived
from quad_msgs.msg import EpisodeStatus, FrameAck, SO3Command
from quad_msgs.srv import Goto

STARTUP_ACK_S = 0.2  # sim seconds after the simulator's first status acknowledged blindly at start-up


class Interrupted(Exception):
    """ROS shut down while waiting."""


def wait_until(
    cv: threading.Condition, predicate: Callable[[], bool], what: str, timeout_wall_s: float
) -> None:
    """Wait on cv (which guards what predicate reads) until predicate() holds. Raises TimeoutError naming
    `what` after timeout_wall_s of wall time, Interrupted on shutdown."""
    deadline = time.monotonic() + timeout_wall_s
    with cv:
        while not predicate():
            if rospy.is_shutdown():
                raise Interrupted(what)
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no {what} within {timeout_wall_s:.0f} s (wall)")
            cv.wait(min(left, 0.1))


class FrameGate:
    """Depth frames (their camera_info, same stamp) held one at a time and acknowledged as `consumer`."""

    def __init__(self, consumer: str, lockstep: bool, wall_wait_s: float = 30.0) -> None:
        self.consumer = consumer
        self.lockstep = lockstep
        self.wall_wait_s = wall_wait_s
        self.cv = threading.Condition()
        self._first_status: rospy.Time | None = None  # stamp of the first EpisodeStatus received
        self._frames: queue.Queue[tuple[float, rospy.Time]] = queue.Queue()
        self.held: rospy.Time | None = None  # the frame returned by next_frame and not acknowledged yet
        self.startup_stamp: rospy.Time | None = None
        self.startup_ack_s = 0.0
        self.seen_frame = False
        self.first_frame_s: float | None = None
        self.last_frame_s = 0.0
        self._last_ack: rospy.Time | None = None
        # Only a consumer publishes acknowledgements: the simulator starts once it has as many FrameAck
        # publishers as named consumers, so a publisher of a node that is none would let it start too early.
        self.ack_pub = (
            rospy.Publisher("sim/frame_ack", FrameAck, queue_size=10, tcp_nodelay=True) if lockstep else None
        )
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10)
        self._sub = rospy.Subscriber(
            "camera/depth/camera_info", CameraInfo, self._on_frame, queue_size=100, tcp_nodelay=True
        )

    def _on_status(self, msg: EpisodeStatus) -> None:
        with self.cv:
            if self._first_status is None:
                self._first_status = msg.header.stamp
                self.cv.notify_all()

    def has_status(self) -> bool:
        """True once the simulator's first status has arrived (cv is notified then)."""
        return self._first_status is not None

    def _on_frame(self, msg: CameraInfo) -> None:
        self._frames.put((msg.header.stamp.to_sec(), msg.header.stamp))

    def fix_startup(self) -> bool:
        """Fix the start-up acknowledgement from the simulator's first status (only from the first: a later,
        periodic one has a later stamp, which would move the first held frame). False before that status."""
        if self.startup_stamp is None:
            with self.cv:
                stamp = self._first_status
            if stamp is None:
                return False
            self.startup_stamp = stamp + rospy.Duration(STARTUP_ACK_S)
            self.startup_ack_s = self.startup_stamp.to_sec()
        return True

    def next_frame(self, after_s: float) -> tuple[float, rospy.Time]:
        """The next frame stamped at or after after_s, held (older ones are acknowledged and skipped).
        Without lockstep: the newest frame that has arrived."""
        if self.lockstep and self.startup_stamp is None:
            # The first hold comes after the start-up acknowledgement's stamp, whether or not this node got
            # the simulator's first frames: the same frame in every run.
            wait_until(self.cv, self.has_status, "simulator status", self.wall_wait_s)
            self.fix_startup()
        deadline = time.monotonic() + self.wall_wait_s
        while True:
            if rospy.is_shutdown():
                raise Interrupted("waiting for a depth frame")
            try:
                t, stamp = self._frames.get(timeout=0.1)
            except queue.Empty:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no depth frame within {self.wall_wait_s:.0f} s (wall)") from None
                if self.lockstep and not self.seen_frame:
                    self._startup_ack()
                elif self.lockstep and self._last_ack is not None:
                    # Repeating the last acknowledgement is harmless (they are cumulative) and recovers one
                    # lost while the connection to the simulator was being set up.
                    self._publish_ack(self._last_ack)
                continue
            self.seen_frame = True
            self.last_frame_s = t
            if self.first_frame_s is None:
                self.first_frame_s = t
            if t < after_s or t <= self.startup_ack_s:
                self.ack(stamp)
                continue
            if not self.lockstep:  # not holding the simulator: only the newest frame matters
                while not self._frames.empty():
                    t, stamp = self._frames.get_nowait()
                self.last_frame_s = t
            self.held = stamp
            return t, stamp

    def _startup_ack(self) -> None:
        # Only once the simulator can reach this node's frame subscription: an acknowledgement that lets it
        # step on while that connection is still being set up would lose the frames this node must hold.
        if self._sub.get_num_connections() == 0 or not self.fix_startup():
            return
        self._publish_ack(self.startup_stamp)

    def _publish_ack(self, stamp: rospy.Time) -> None:
        if self.ack_pub is not None:
            self.ack_pub.publish(FrameAck(consumer=self.consumer, frame_seq=0, stamp=stamp))

    def ack(self, stamp: rospy.Time | None = None) -> None:
        """Acknowledge a frame (default: the held one), releasing the simulator up to it."""
        stamp = stamp or self.held
        if stamp is None:
            return
        if self.lockstep:
            self._publish_ack(stamp)
            if self._last_ack is None or stamp > self._last_ack:
                self._last_ack = stamp
        if stamp == self.held:
            self.held = None


class OdometryHistory:
    """Odometry by stamp (position, speed), for decisions taken at a frame from the odometry at or before it.
    Keeps the newest `keep` messages (None: all since the last `clear`, e.g. a whole episode's path)."""

    def __init__(
        self, odom_period_s: float = 0.005, keep: int | None = 2000, wall_wait_s: float = 30.0
    ) -> None:
        self.odom_period_s = odom_period_s
        self.wall_wait_s = wall_wait_s
        self._keep = keep
        self.cv = threading.Condition()
        self._t: list[float] = []
        self._v: list[tuple[tuple[float, float, float], float]] = []
        rospy.Subscriber("odom", Odometry, self._on_odom, queue_size=400, tcp_nodelay=True)

    def _on_odom(self, msg: Odometry) -> None:
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        with self.cv:
            t = msg.header.stamp.to_sec()
            if self._t and t < self._t[-1]:  # a new episode never goes back in time; be safe
                self._t.clear()
                self._v.clear()
            self._t.append(t)
            self._v.append(((p.x, p.y, p.z), math.hypot(v.x, v.y, v.z)))
            if self._keep is not None and len(self._t) > self._keep:
                del self._t[: self._keep // 2]
                del self._v[: self._keep // 2]
            self.cv.notify_all()

    def at(self, t: float) -> tuple[tuple[float, float, float], float]:
        """(position, speed) of the newest odometry stamped at or before t, waiting until the one within an
        odometry period of t has arrived (in lockstep it was published before the frame at t)."""
        wait_until(
            self.cv,
            lambda: bool(self._t) and period_arrived(self._t[-1], t, self.odom_period_s),
            f"odometry at t={t:.3f}",
            self.wall_wait_s,
        )
        with self.cv:
            return self._v[max(newest_at_or_before(self._t, t), 0)]

    def positions(self, t0: float, t1: float) -> list[tuple[float, float, float, float]]:
        """(stamp, x, y, z) of every message kept stamped in [t0, t1]."""
        eps = 1e-6
        with self.cv:
            i, j = bisect.bisect_left(self._t, t0 - eps), bisect.bisect_right(self._t, t1 + eps)
            return [(t, *v[0]) for t, v in zip(self._t[i:j], self._v[i:j], strict=True)]

    def clear(self) -> None:
        with self.cv:
            self._t.clear()
            self._v.clear()


class TrackerGoto:
    """The tracker's goto service, called at a held frame so that the goto takes effect at the same step in
    every run: the tracker applies a goto from the next odometry it processes, so the call waits until the
    tracker has answered the odometry of the frame's control period (its SO3Command of that stamp)."""

    def __init__(self, lockstep: bool, odom_period_s: float = 0.005, wall_wait_s: float = 30.0) -> None:
        self.lockstep = lockstep
        self.odom_period_s = odom_period_s
        self.wall_wait_s = wall_wait_s
        self.cv = threading.Condition()
        self._cmd_t = 0.0  # stamp of the tracker's newest command
        rospy.Subscriber("so3_cmd", SO3Command, self._on_cmd, queue_size=100, tcp_nodelay=True)

    def _on_cmd(self, msg: SO3Command) -> None:
        with self.cv:
            self._cmd_t = msg.header.stamp.to_sec()
            self.cv.notify_all()

    def __call__(self, position: tuple[float, float, float], yaw: float, at_s: float | None = None) -> str:
        """'' if the tracker took the goto, else its reason. at_s: the held frame's stamp (lockstep)."""
        if at_s is not None and self.lockstep:
            wait_until(
                self.cv,
                lambda: period_arrived(self._cmd_t, at_s, self.odom_period_s),
                f"tracker command of the control period at t={at_s:.3f}",
                self.wall_wait_s,
            )
        goto = rospy.ServiceProxy("tracker/goto", Goto)
        r = goto(position=Point(*position), yaw=yaw, max_vel_mps=0.0, max_acc_mps2=0.0)
        return "" if r.success else r.message


class ControllerGoal:
    """The goal of an episode, given to the controller (the expert planner or a policy node) at a held frame.
    With `wait`: published once the controller has acknowledged that frame (so the goal counts from its next
    frame on, in every run), and `give` returns once the controller has answered it on its status topic
    ("goal accepted: ..." / "goal rejected: ..."), before the frame is released. Without: just published."""

    def __init__(self, consumer: str, status_topic: str, wait: bool, wall_wait_s: float = 30.0) -> None:
        self.consumer = consumer
        self.wait = wait
        self.wall_wait_s = wall_wait_s
        self.cv = threading.Condition()
        self._ack_s = 0.0
        self._answers: list[str] = []
        self.goal_pub = rospy.Publisher("planner/goal", PoseStamped, queue_size=1, latch=True)
        if wait:  # (a subscriber would count as connected for the nodes that wait for one)
            rospy.Subscriber(status_topic, String, self._on_answer, queue_size=100)
            rospy.Subscriber("sim/frame_ack", FrameAck, self._on_ack, queue_size=200, tcp_nodelay=True)

    def _on_answer(self, msg: String) -> None:
        with self.cv:
            self._answers.append(msg.data)
            self.cv.notify_all()

    def _on_ack(self, msg: FrameAck) -> None:
        if msg.consumer == self.consumer:
            with self.cv:
                self._ack_s = max(self._ack_s, msg.stamp.to_sec())
                self.cv.notify_all()

    def give(self, goal_world: tuple[float, float, float], t: float) -> str:
        """Publish the goal (stamped t) at the held frame t; returns the controller's answer ('' without
        `wait`)."""
        if self.wait:
            wait_until(
                self.cv,
                lambda: self._ack_s >= t - 1e-9,
                f"acknowledgement of frame {t:.3f} by {self.consumer}",
                self.wall_wait_s,
            )
        with self.cv:
            n_answers = len(self._answers)
        goal = PoseStamped()
        goal.header.stamp = rospy.Time.from_sec(t)
        goal.header.frame_id = "world"
        goal.pose.position = Point(*goal_world)
        goal.pose.orientation.w = 1.0
        self.goal_pub.publish(goal)
        if not self.wait:
            return ""
        answer: list[str] = []

        def answered() -> bool:
            for a in self._answers[n_answers:]:
                if a.startswith(("goal accepted", "goal rejected")):
                    answer.append(a)
                    return True
            return False

        wait_until(self.cv, answered, f"answer of {self.consumer} to the goal", self.wall_wait_s)
        return answer[0]

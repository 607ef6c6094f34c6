"""One decision of the learned policy (the Python twin of quad_policy/policy_decider.h).

depth frame + odometry + goal -> preprocessing -> network -> world-frame B-spline started at the frame's stamp
-> safety layer -> the trajectory to send: the policy's (with several hypotheses, the most confident one's);
when refused, the first accepted plan of the recovery (the policy's other hypotheses in order of confidence,
then the network asked again with the goal turned about the vehicle, `recovery.goal_yaw_offsets_deg`); else,
with `keeping.on_refusal`, nothing while the rest of the trajectory sent before is still clear; else the
stopping trajectory when the refusal action is `stop`. With `keeping.commit_s`, a plan sent is flown on
(nothing sent) while it is younger than that and its rest is clear. ROS-free: the rospy node, the parity test
and the benchmark call `decide`."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quad_il.inference.config import (
    KeepingConfig,
    RecoveryConfig,
    RefusalConfig,
    SafetyConfig,
    check_steering,
    check_turning,
)
from quad_il.inference.fixture import DecisionFixture
from quad_il.inference.geometry import yaw_of
from quad_il.inference.policy import LoadedPolicy, ordered_plans
from quad_il.inference.preprocessing import PolicyPreprocessing, as_row
from quad_il.inference.safety import (
    CameraModel,
    DepthMemory,
    SafetyResult,
    VerdictCounts,
    check_trajectory,
    nearest_depth,
    rest_is_clear,
    trajectory_in_view,
)
from quad_il.inference.trajectory import (
    UniformBspline,
    braking_trajectory,
    final_approach,
    policy_trajectory,
    turning_stop,
)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DecisionInputs:
    stamp_s: float  # the depth frame's stamp: the trajectory starts here
    depth_m: NDArray[np.float32]  # (H, W) metres, REP 118
    camera: CameraModel  # intrinsics and the camera's pose at the frame (from the odometry below)
    p_world_body: FloatArray
    v_world: FloatArray
    q_world_body: FloatArray  # x, y, z, w
    goal_world: FloatArray


def fixture_inputs(fx: DecisionFixture, i: int) -> DecisionInputs:
    """Frame i of a recorded fixture as decision inputs (the benchmark and the parity test)."""
    return DecisionInputs(
        float(fx.stamp_s[i]),
        fx.depth_m[i],
        fx.camera(i),
        fx.p_world_body[i],
        fx.v_world[i],
        fx.q_world_body[i],
        fx.goal_world[i],
    )


@dataclass
class DecisionTimings:
    preprocess_ms: float = 0.0  # depth + state encoding
    forward_ms: float = 0.0  # the network
    decode_ms: float = 0.0  # output decoding + trajectory
    safety_ms: float = 0.0  # the safety layer (and the recovery's plans or the stopping trajectory)


@dataclass
class Decision:
    safety: SafetyResult
    proposed: UniformBspline
    stop: UniformBspline | None
    depth_x: NDArray[np.float32]  # (input_height, input_width)
    state_x: NDArray[np.float32]  # (13,)
    y: NDArray[np.float32]  # (network_output_dim,): the network's output, every hypothesis
    proposed_hypothesis: int = 0  # index of the hypothesis `proposed` comes from (the most confident)
    timings: DecisionTimings = field(default_factory=DecisionTimings)
    # When the policy's plan was refused (or, steering, came nearer than steer_clearance_m) and another
    # hypothesis or a turned goal gave a plan that passed: that plan, the angle (0: the goal itself) and the
    # hypothesis' index.
    recovery: UniformBspline | None = None
    recovery_yaw_deg: float | None = None
    recovery_hypothesis: int | None = None
    recovery_tries: int = 0  # turned goals asked (0 when no search ran)
    steered: bool = False  # the recovery replaces an accepted plan (steering), not a refused one
    turn_rate_radps: float = 0.0  # non-zero: the stopping trajectory turns in place at this rate
    turn_backoff_m: float = 0.0  # and backs away along the heading by this much
    # Within recovery.final_approach_m of the goal: the trajectory straight to the goal, when the safety layer
    # accepted it (it is then sent instead of anything else).
    final: UniformBspline | None = None
    # KeepingConfig: the plan sent before, flown on (nothing is sent): committed (younger than commit_s) or,
    # on a refusal the recovery could not mend (on_refusal), with its rest still clear.
    kept: UniformBspline | None = None
    committed: bool = False  # kept because its commitment had not ended (else kept on a refusal)

    @property
    def accepted(self) -> bool:
        return self.safety.accepted

    def recovery_text(self, num_hypotheses: int) -> str:
        """ "; recovered with ..." for the decision's reason ("" without a recovery); the C++ node writes the
        same words (RecoveryText)."""
        if self.recovery is None:
            return ""
        what = "steered" if self.steered else "recovered"
        yaw = self.recovery_yaw_deg or 0.0
        if num_hypotheses == 1:
            return f"; {what} with the goal turned {yaw:g} deg"
        hyp = f"hypothesis {(self.recovery_hypothesis or 0) + 1} of {num_hypotheses}"  # numbered from 1
        if yaw == 0.0:
            return f"; {what} with {hyp}"
        return f"; {what} with the goal turned {yaw:g} deg, {hyp}"

    def to_send(self) -> UniformBspline | None:
        if self.kept is not None:
            return None
        if self.final is not None:
            return self.final
        if self.recovery is not None:
            return self.recovery
        if self.accepted:
            return self.proposed
        return self.stop


def turned_goal(p_world_body: FloatArray, goal_world: FloatArray, yaw_deg: float) -> FloatArray:
    """The goal turned by yaw_deg about the vertical axis through the vehicle (same distance and height)."""
    a = math.radians(yaw_deg)
    c, s = math.cos(a), math.sin(a)
    p = np.asarray(p_world_body, dtype=np.float64).reshape(3)
    d = np.asarray(goal_world, dtype=np.float64).reshape(3) - p
    return p + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]])


class PolicyDecider:
    def __init__(
        self,
        policy: LoadedPolicy,
        safety: SafetyConfig,
        refusal: RefusalConfig,
        recovery: RecoveryConfig | None = None,
        keeping: KeepingConfig | None = None,
    ) -> None:
        self.policy = policy
        self.keeping = keeping if keeping is not None else KeepingConfig(commit_s=0.0, on_refusal=False)
        self.safety = safety
        self.refusal = refusal
        self.recovery = (
            recovery
            if recovery is not None
            else RecoveryConfig(
                goal_yaw_offsets_deg=[],
                steer_clearance_m=0.0,
                turn_after_stops=0,
                turn_rate_dps=45.0,
                turn_clearance_m=0.0,
                final_approach_m=0.0,
                final_approach_acc_mps2=2.0,
            )
        )
        check_steering(self.recovery, safety)
        check_turning(self.recovery, refusal)
        self.steer_safety = safety.model_copy(update={"vehicle_radius_m": self.recovery.steer_clearance_m})
        self.pre = PolicyPreprocessing(policy.meta)
        self.counts = VerdictCounts()
        self.stops_in_row = 0  # consecutive decisions that sent the stopping trajectory
        self.turn_sign = 0  # +1 left, -1 right, 0: not turning
        self.memory = DepthMemory(safety.memory_frames, safety.memory_spacing_s)
        self.sent: UniformBspline | None = None  # the trajectory the tracker flies (KeepingConfig)

    def reset(self) -> None:
        """A new episode: forgets the stops in a row, the turning direction, the depth memory and the
        trajectory sent last."""
        self._end_stops()
        self.memory.clear()
        self.sent = None

    def _end_stops(self) -> None:
        self.stops_in_row = 0
        self.turn_sign = 0

    def decide(self, inp: DecisionInputs) -> Decision:
        """Raises ValueError on invalid inputs (non-finite odometry or goal, empty depth)."""
        if not math.isfinite(inp.stamp_s):
            raise ValueError("depth stamp is not finite")
        t0 = time.perf_counter()
        depth_x = self.pre.depth(inp.depth_m)
        p = as_row(inp.p_world_body, 3, "p_world_body")
        v = as_row(inp.v_world, 3, "v_world")
        q = as_row(inp.q_world_body, 4, "q_world_body")
        goal = as_row(inp.goal_world, 3, "goal_world")
        state_x = self.pre.state(p, v, q, goal)
        t1 = time.perf_counter()
        y = self.policy.run(depth_x, state_x, p, v, q, goal)
        t2 = time.perf_counter()
        meta = self.policy.meta
        plans = ordered_plans(y, meta)
        proposed = policy_trajectory(self.pre.decode(plans[0][1], p, q), meta, inp.stamp_s)
        t3 = time.perf_counter()
        mem = self.memory.frames  # the earlier frames, newest first (this one is added after the decision)
        result = check_trajectory(proposed, inp.p_world_body, inp.depth_m, inp.camera, self.safety, mem)
        rest_clear: list[bool] = []  # the rest of the plan sent before, judged at most once (KeepingConfig)

        def sent_rest_is_clear(sent: UniformBspline) -> bool:
            if not rest_clear:
                rest_clear.append(
                    rest_is_clear(
                        sent,
                        inp.stamp_s,
                        max(self.safety.check_horizon_s, self.refusal.stop_min_duration_s),
                        inp.p_world_body,
                        inp.depth_m,
                        inp.camera,
                        self.safety,
                        mem,
                    )
                )
            return rest_clear[0]

        # A committed plan is flown on while it is younger than commit_s and its rest is clear: nothing else
        # is tried (the network's plan is still computed, for the record and the timings).
        kept = None
        committed = False
        if (
            self.keeping.commit_s > 0.0
            and self.sent is not None
            and inp.stamp_s - self.sent.start_time_s < self.keeping.commit_s
            and sent_rest_is_clear(self.sent)
        ):
            kept, committed = self.sent, True
        final = None
        to_goal = np.asarray(inp.goal_world, np.float64).reshape(3) - np.asarray(
            inp.p_world_body, np.float64
        ).reshape(3)
        if kept is None and float(np.linalg.norm(to_goal)) < self.recovery.final_approach_m:  # 0: off
            traj = final_approach(
                inp.p_world_body,
                inp.v_world,
                inp.goal_world,
                self.recovery.final_approach_acc_mps2,
                self.refusal.stop_min_duration_s,
                inp.stamp_s,
            )
            if (
                traj is not None
                and check_trajectory(
                    traj, inp.p_world_body, inp.depth_m, inp.camera, self.safety, mem
                ).accepted
            ):
                final = traj
        recovery: UniformBspline | None = None
        recovery_yaw: float | None = None
        recovery_h: int | None = None
        tries = 0
        # A refused proposal is replaced by the first other plan that the safety layer accepts and that stays
        # in view: the policy's other hypotheses (most confident first, no extra forward pass), then for each
        # turned goal its hypotheses. Steering: an accepted proposal that comes nearer than
        # steer_clearance_m is replaced by the first such plan that, besides, keeps steer_clearance_m (the
        # wider sphere skips the samples it holds the camera in, so it adds to the safety layer's test, never
        # replaces it).
        steering = (
            result.accepted
            and self.recovery.steer_clearance_m > 0.0
            and not check_trajectory(
                proposed, inp.p_world_body, inp.depth_m, inp.camera, self.steer_safety, mem
            ).accepted
        )
        if kept is None and final is None and (not result.accepted or steering):
            # Yaw 0 (never a configured turn: those are non-zero) stands for the goal itself.
            for yaw in [0.0, *self.recovery.goal_yaw_offsets_deg]:
                if yaw == 0.0:
                    alternatives = plans[1:]
                else:
                    tries += 1
                    g = as_row(turned_goal(inp.p_world_body, inp.goal_world, yaw), 3, "goal_world")
                    alternatives = ordered_plans(
                        self.policy.run(depth_x, self.pre.state(p, v, q, g), p, v, q, g), meta
                    )
                for h, y_h in alternatives:
                    traj = policy_trajectory(self.pre.decode(y_h, p, q), meta, inp.stamp_s)
                    if (
                        check_trajectory(
                            traj, inp.p_world_body, inp.depth_m, inp.camera, self.safety, mem
                        ).accepted
                        and (
                            not steering
                            or check_trajectory(
                                traj, inp.p_world_body, inp.depth_m, inp.camera, self.steer_safety, mem
                            ).accepted
                        )
                        and trajectory_in_view(traj, inp.camera, self.safety, mem)
                    ):
                        recovery, recovery_yaw, recovery_h = traj, yaw, h
                        break
                if recovery is not None:
                    break
        # Keeping the plan on a refusal: not recovered, the tracker flies on along the trajectory sent before
        # while its rest from now on passes the test a recovery plan passes.
        if (
            self.keeping.on_refusal
            and kept is None
            and not result.accepted
            and recovery is None
            and final is None
            and self.sent is not None
            and sent_rest_is_clear(self.sent)
        ):
            kept = self.sent
        stop = None
        turn_rate = 0.0
        backoff = 0.0
        if (
            not result.accepted
            and recovery is None
            and final is None
            and kept is None
            and self.refusal.action == "stop"
        ):
            self.stops_in_row += 1
            n = self.recovery.turn_after_stops
            if n > 0 and self.stops_in_row >= n:
                yaw = yaw_of(np.asarray(inp.q_world_body, dtype=np.float64).reshape(4))
                p0 = np.asarray(inp.p_world_body, np.float64).reshape(3)
                if self.turn_sign == 0:
                    # Towards the side the goal lies on (left when straight ahead or behind).
                    to_goal = np.asarray(inp.goal_world, np.float64).reshape(3) - p0
                    bearing = math.remainder(
                        math.atan2(float(to_goal[1]), float(to_goal[0])) - yaw, 2.0 * math.pi
                    )
                    self.turn_sign = -1 if bearing < 0.0 else 1
                turn_rate = self.turn_sign * math.radians(self.recovery.turn_rate_dps)
                # Room to turn: back away from a surface nearer than turn_clearance_m.
                backoff = max(0.0, self.recovery.turn_clearance_m - nearest_depth(inp.depth_m))
                stop = turning_stop(
                    p0,
                    inp.v_world,
                    -backoff * np.array([math.cos(yaw), math.sin(yaw), 0.0]),
                    yaw,
                    turn_rate,
                    self.refusal.stop_max_decel_mps2,
                    self.refusal.stop_min_duration_s,
                    inp.stamp_s,
                )
            else:
                stop = braking_trajectory(
                    inp.p_world_body,
                    inp.v_world,
                    self.refusal.stop_max_decel_mps2,
                    self.refusal.stop_min_duration_s,
                    inp.stamp_s,
                )
        else:
            self._end_stops()
        self.memory.add(inp.stamp_s, inp.depth_m, inp.camera)
        t4 = time.perf_counter()
        self.counts.add(result.verdict)
        decision = Decision(
            safety=result,
            proposed=proposed,
            stop=stop,
            depth_x=depth_x[0, 0].numpy().copy(),
            state_x=state_x[0].numpy().copy(),
            y=y[0].numpy().copy(),
            proposed_hypothesis=plans[0][0],
            timings=DecisionTimings(1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2), 1e3 * (t4 - t3)),
            recovery=recovery,
            recovery_yaw_deg=recovery_yaw,
            recovery_hypothesis=recovery_h,
            recovery_tries=tries,
            steered=steering and recovery is not None,
            turn_rate_radps=turn_rate,
            turn_backoff_m=backoff,
            final=final,
            kept=kept,
            committed=committed,
        )
        # The plan the tracker now flies; a stopping trajectory is never kept (the next refusal stops anew).
        if kept is None:
            sent = decision.to_send()
            self.sent = sent if sent is not None and sent is not decision.stop else None
        return decision

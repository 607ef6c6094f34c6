"""One decision of the learned policy (the Python twin of quad_policy/policy_decider.h).

depth frame + odometry + goal -> preprocessing -> network -> world-frame B-spline started at the frame's stamp
-> safety layer -> the trajectory to send (the policy's, or the stopping trajectory when refused and the
refusal action is `stop`). ROS-free: the rospy node, the parity test and the benchmark call `decide`."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quad_il.inference.config import RefusalConfig, SafetyConfig
from quad_il.inference.policy import LoadedPolicy
from quad_il.inference.preprocessing import PolicyPreprocessing, as_row
from quad_il.inference.safety import CameraModel, SafetyResult, VerdictCounts, check_trajectory
from quad_il.inference.trajectory import UniformBspline, braking_trajectory, policy_trajectory

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


@dataclass
class DecisionTimings:
    preprocess_ms: float = 0.0  # depth + state encoding
    forward_ms: float = 0.0  # the network
    decode_ms: float = 0.0  # output decoding + trajectory
    safety_ms: float = 0.0  # the safety layer (and the stopping trajectory)


@dataclass
class Decision:
    safety: SafetyResult
    proposed: UniformBspline
    stop: UniformBspline | None
    depth_x: NDArray[np.float32]  # (input_height, input_width)
    state_x: NDArray[np.float32]  # (13,)
    y: NDArray[np.float32]  # (output_dim,)
    timings: DecisionTimings = field(default_factory=DecisionTimings)

    @property
    def accepted(self) -> bool:
        return self.safety.accepted

    def to_send(self) -> UniformBspline | None:
        return self.proposed if self.accepted else self.stop


class PolicyDecider:
    def __init__(self, policy: LoadedPolicy, safety: SafetyConfig, refusal: RefusalConfig) -> None:
        self.policy = policy
        self.safety = safety
        self.refusal = refusal
        self.pre = PolicyPreprocessing(policy.meta)
        self.counts = VerdictCounts()

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
        proposed = policy_trajectory(self.pre.decode(y, p, q), self.policy.meta, inp.stamp_s)
        t3 = time.perf_counter()
        result = check_trajectory(proposed, inp.p_world_body, inp.depth_m, inp.camera, self.safety)
        stop = None
        if not result.accepted and self.refusal.action == "stop":
            stop = braking_trajectory(
                inp.p_world_body,
                inp.v_world,
                self.refusal.stop_max_decel_mps2,
                self.refusal.stop_min_duration_s,
                inp.stamp_s,
            )
        t4 = time.perf_counter()
        self.counts.add(result.verdict)
        return Decision(
            safety=result,
            proposed=proposed,
            stop=stop,
            depth_x=depth_x[0, 0].numpy().copy(),
            state_x=state_x[0].numpy().copy(),
            y=y[0].numpy().copy(),
            timings=DecisionTimings(1e3 * (t1 - t0), 1e3 * (t2 - t1), 1e3 * (t3 - t2), 1e3 * (t4 - t3)),
        )

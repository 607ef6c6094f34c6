"""Deterministic preprocessing shared by training and the exported policy (docs/learning.md, "Preprocessing").

Everything here is a TorchScript-compatible `nn.Module`, so the exported policy file carries the exact same
code and parameters: the inference nodes (Python and C++, issue 8) feed raw depth in metres and the raw
odometry/goal, and the file does the rest. Training caches the output of `DepthPreprocessor` once per sample
(float16, lossless because the preprocessor rounds to float16 itself), so the cached tensors equal what the
exported file computes.

Frames: `world` is ENU; the `local` frame is the yaw-only vehicle frame: origin at p_world_body, z up, x along
the vehicle's heading projected on the horizontal plane (the frame of the dataset's `bspline_ctrl_local`).
Quaternions are (x, y, z, w) (docs/CONVENTIONS.md).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from quad_il.data.bspline import basis_matrix, uniform_knots

STATE_DIM = 13  # position (3), velocity (3), orientation quaternion xyzw (4), goal (3)


def yaw_from_quaternion(q_xyzw: Tensor) -> Tensor:
    """Yaw (rad, about world z) of rotations given as (..., 4) xyzw quaternions (need not be normalised)."""
    x, y, z, w = q_xyzw[..., 0], q_xyzw[..., 1], q_xyzw[..., 2], q_xyzw[..., 3]
    return torch.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def world_to_local_points(points_world: Tensor, p_world_body: Tensor, yaw: Tensor) -> Tensor:
    """(B, K, 3) world points -> yaw-only vehicle frame: R_z(yaw)^T (p - p_world_body)."""
    c = torch.cos(yaw).unsqueeze(1)
    s = torch.sin(yaw).unsqueeze(1)
    d = points_world - p_world_body.unsqueeze(1)
    x = c * d[..., 0] + s * d[..., 1]
    y = -s * d[..., 0] + c * d[..., 1]
    return torch.stack([x, y, d[..., 2]], dim=-1)


def local_to_world_points(points_local: Tensor, p_world_body: Tensor, yaw: Tensor) -> Tensor:
    """Inverse of `world_to_local_points`: R_z(yaw) p_local + p_world_body."""
    c = torch.cos(yaw).unsqueeze(1)
    s = torch.sin(yaw).unsqueeze(1)
    x = c * points_local[..., 0] - s * points_local[..., 1]
    y = s * points_local[..., 0] + c * points_local[..., 1]
    return torch.stack([x, y, points_local[..., 2]], dim=-1) + p_world_body.unsqueeze(1)


def _quaternion_product(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product a b of (..., 4) xyzw quaternions."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        dim=-1,
    )


def mirror_about_heading(
    p_world_body: Tensor,
    v_world: Tensor,
    q_world_body: Tensor,
    goal_world: Tensor,
    points_world: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
    """The sample seen in a mirror: reflection about the vertical plane through p_world_body along the
    vehicle's heading (M = R_z(yaw) S R_z(-yaw), S = diag(1, -1, 1)). The world is mirror-symmetric under it
    (gravity is vertical; the camera sits on the body's x axis, looking along it, with its principal point at
    the image's centre), so the reflected state, goal and plan make a valid sample whose depth image is the
    original flipped left to right (training's `data.mirror_probability`).

    p (B,3) stays; v' = M v; goal' = p + M (goal - p); points (B,K,3)' = p + M (points - p); the attitude
    R = R_z(yaw) R_l becomes M R S = R_z(yaw) S R_l S: the yaw is kept and the roll-pitch part R_l is
    mirrored, as a quaternion q_l = (x, y, z, w) -> (-x, y, -z, w). Mirroring twice gives the sample back.
    Returns (v', q', goal', points') (points' None without points)."""
    yaw = yaw_from_quaternion(q_world_body)
    n = torch.stack([-torch.sin(yaw), torch.cos(yaw), torch.zeros_like(yaw)], dim=-1)  # (B, 3): M = I - 2nn^T

    def reflect(x: Tensor) -> Tensor:  # (B, ..., 3), n broadcast over the middle dimensions
        nb = n.view(n.shape[0], *([1] * (x.dim() - 2)), 3)
        return x - 2.0 * (x * nb).sum(-1, keepdim=True) * nb

    zeros = torch.zeros_like(yaw)
    q_yaw = torch.stack([zeros, zeros, torch.sin(0.5 * yaw), torch.cos(0.5 * yaw)], dim=-1)
    q_yaw_inv = q_yaw * q_yaw.new_tensor([-1.0, -1.0, -1.0, 1.0])
    q_l = _quaternion_product(q_yaw_inv, q_world_body)
    q_l = q_l * q_l.new_tensor([-1.0, 1.0, -1.0, 1.0])
    q = _quaternion_product(q_yaw, q_l)
    goal = p_world_body + reflect(goal_world - p_world_body)
    points = (
        None
        if points_world is None
        else p_world_body.unsqueeze(1) + reflect(points_world - p_world_body.unsqueeze(1))
    )
    return reflect(v_world), q, goal, points


def _canonical_unit_quaternion(q: Tensor) -> Tensor:
    """Unit quaternion with w >= 0 (q and -q are the same rotation; one sign makes the input a function)."""
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(1e-12)
    sign = torch.where(q[..., 3:4] < 0.0, -torch.ones_like(q[..., 3:4]), torch.ones_like(q[..., 3:4]))
    return q * sign


class DepthPreprocessor(nn.Module):
    """Raw depth (B, H, W) or (B, 1, H, W) in metres -> network input (B, 1, out_h, out_w) float32 in [0, 1].

    1. float32; REP 118 specials: +inf (no return) and NaN (invalid) -> max_depth_m, -inf (too near) -> 0;
       clamp to [0, max_depth_m].
    2. Area resize to (out_h, out_w) with `adaptive_avg_pool2d` (each output pixel is the mean of the input
       pixels its cell covers; exact block means when H, W are multiples of out_h, out_w).
    3. Divide by max_depth_m.
    4. Round to float16 and back, so that the training cache (stored as float16) holds exactly these values.
    """

    def __init__(self, out_height: int, out_width: int, max_depth_m: float) -> None:
        super().__init__()
        if out_height < 8 or out_width < 8:
            raise ValueError(f"input size must be at least 8x8, got {out_height}x{out_width}")
        if not max_depth_m > 0.0:
            raise ValueError(f"max_depth_m must be > 0, got {max_depth_m}")
        self.out_height = int(out_height)
        self.out_width = int(out_width)
        self.max_depth_m = float(max_depth_m)

    def forward(self, depth_m: Tensor) -> Tensor:
        if depth_m.dim() == 3:
            depth_m = depth_m.unsqueeze(1)
        if depth_m.dim() != 4 or depth_m.size(1) != 1:
            raise RuntimeError("depth must be (B, H, W) or (B, 1, H, W) metres")
        # A private float32 copy, modified in place (two passes over the full-resolution image, no
        # temporaries): clamp maps +inf to max_depth_m and -inf to 0 and keeps NaN, which nan_to_num then maps
        # to max_depth_m.
        d = depth_m.to(dtype=torch.float32, copy=True)
        d.clamp_(0.0, self.max_depth_m)
        d.nan_to_num_(nan=self.max_depth_m)
        d = F.adaptive_avg_pool2d(d, [self.out_height, self.out_width])
        x = d / self.max_depth_m
        return x.to(torch.float16).to(torch.float32)


class StateEncoder(nn.Module):
    """(p_world_body, v_world, q_world_body xyzw, goal_world) -> (B, 13) state vector for the state MLP.

    world frame (thesis): [p / s_p, v / s_v, q, goal / s_p].
    local frame: [(0, 0, z_world) / s_p, R^T v / s_v, q_local, R^T (goal - p) / s_p] with R = R_z(yaw);
    q_local is the attitude without its yaw (roll and pitch only); z_world is kept because height above ground
    matters. Quaternions are normalised and given w >= 0. s_p = position_scale_m, s_v = velocity_scale_mps.
    """

    def __init__(
        self,
        local_frame: bool,
        position_scale_m: float,
        velocity_scale_mps: float,
        velocity_input: bool = True,
    ) -> None:
        super().__init__()
        if not (position_scale_m > 0.0 and velocity_scale_mps > 0.0):
            raise ValueError(f"state scales must be > 0, got {position_scale_m}, {velocity_scale_mps}")
        self.local_frame = bool(local_frame)
        # False: the velocity entries are zero (model.velocity_input; the network cannot copy the vehicle's
        # motion into its plan).
        self.velocity_gain = 1.0 if velocity_input else 0.0
        self.position_scale_m = float(position_scale_m)
        self.velocity_scale_mps = float(velocity_scale_mps)

    def forward(
        self, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        q = _canonical_unit_quaternion(q_world_body)
        if not self.local_frame:
            return torch.cat(
                [
                    p_world_body / self.position_scale_m,
                    v_world * (self.velocity_gain / self.velocity_scale_mps),
                    q,
                    goal_world / self.position_scale_m,
                ],
                dim=1,
            )
        yaw = yaw_from_quaternion(q)
        c = torch.cos(yaw)
        s = torch.sin(yaw)
        zeros = torch.zeros_like(c)
        p_local = torch.stack([zeros, zeros, p_world_body[:, 2]], dim=1)
        v_local = torch.stack(
            [c * v_world[:, 0] + s * v_world[:, 1], -s * v_world[:, 0] + c * v_world[:, 1]], 1
        )
        v_local = torch.cat([v_local, v_world[:, 2:3]], dim=1)
        goal_local = world_to_local_points(goal_world.unsqueeze(1), p_world_body, yaw).squeeze(1)
        # q_local = q_yaw^-1 * q (Hamilton product, xyzw), with q_yaw^-1 = (0, 0, -sin(yaw/2), cos(yaw/2)).
        ch = torch.cos(0.5 * yaw)
        sh = torch.sin(0.5 * yaw)
        qx, qy, qz, qw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        q_local = torch.stack([ch * qx + sh * qy, ch * qy - sh * qx, ch * qz - sh * qw, ch * qw + sh * qz], 1)
        q_local = _canonical_unit_quaternion(q_local)
        return torch.cat(
            [
                p_local / self.position_scale_m,
                v_local * (self.velocity_gain / self.velocity_scale_mps),
                q_local,
                goal_local / self.position_scale_m,
            ],
            dim=1,
        )


# Uniform cubic B-spline in matrix form (Qin, "General matrix representations for B-splines", 2000):
# p(u) = [1 u u^2 u^3] M [c_k .. c_k+3]^T for u in [0, 1] on segment k.
def uniform_cubic_basis(num_ctrl_pts: int, num_samples: int) -> Tensor:
    """(S, K) float64 matrix A with A[j, i] = N_i(s_j) for the dataset's B-spline representation.

    The dataset's K control points define a uniform cubic B-spline with knots (i - 3) dt, i = 0..K+3,
    dt = horizon_s / (K - 3), whose domain [0, horizon_s] spans K - 3 segments (docs/data_format.md); the
    samples s_j are evenly spaced over the domain, both ends included. The matrix does not depend on
    horizon_s, so it is computed with dt = 1 by the project's one B-spline evaluator (quad_il.data.bspline).
    """
    if num_ctrl_pts < 4:
        raise ValueError(f"a cubic B-spline needs num_ctrl_pts >= 4, got {num_ctrl_pts}")
    if num_samples < 2:
        raise ValueError(f"num_samples must be >= 2, got {num_samples}")
    u = np.linspace(0.0, float(num_ctrl_pts - 3), num_samples)
    return torch.from_numpy(basis_matrix(uniform_knots(num_ctrl_pts, 3, 1.0), num_ctrl_pts, 3, u))


def polynomial_maps(num_ctrl_pts: int, degree: int) -> tuple[Tensor, Tensor]:
    """(E, D) float64: coefficients C = E X of control points X (K x 3), and control points X = D C.

    The polynomial output describes the trajectory itself: p(tau) = sum_d C[d] tau^d with the normalised time
    tau = 2 t / horizon_s - 1 in [-1, 1] (centred: the monomial basis is far better conditioned on [-1, 1]
    than on [0, 1]). C is the least-squares fit of the B-spline sampled densely over its domain (S = 16 (K -
    3) + 1 samples): E = pinv(T) A with A = uniform_cubic_basis and T[j, d] = tau_j^d; decoding samples the
    polynomial and fits the B-spline back: D = pinv(A) T. Exact for trajectories that are polynomials of
    degree <= 3 (which uniform cubic B-splines reproduce); otherwise the least-squares projection onto degree
    `degree`.
    """
    if degree < 1:
        raise ValueError(f"poly_degree must be >= 1, got {degree}")
    num_samples = 16 * (num_ctrl_pts - 3) + 1
    if degree + 1 > num_samples:
        raise ValueError(f"poly_degree {degree} is too high for {num_ctrl_pts} control points")
    a = uniform_cubic_basis(num_ctrl_pts, num_samples)
    tau = torch.linspace(-1.0, 1.0, num_samples, dtype=torch.float64)
    t = tau.unsqueeze(1) ** torch.arange(degree + 1, dtype=torch.float64).unsqueeze(0)
    return torch.linalg.pinv(t) @ a, torch.linalg.pinv(a) @ t


def constant_velocity_prior(
    num_ctrl_pts: int,
    horizon_s: float,
    local_frame: bool,
    polynomial: bool,
    poly_degree: int,
    position_scale_m: float,
    velocity_scale_mps: float,
) -> Tensor:
    """(out_dim, STATE_DIM) float32 M: M @ state_vector is the network output, in the training representation,
    of flying on at constant velocity from the current state (model.output_prior = constant_velocity).

    On uniform knots (i - 3) dt, dt = horizon_s / (K - 3), the cubic B-spline with control points
    P_i = p + (i - 1) dt v is exactly p(t) = p + t v (p(0) = (P_0 + 4 P_1 + P_2) / 6 = p, p'(0) = v). In the
    local frame (state and output in the yaw-only vehicle frame) p is the origin and v the state's R^T v; in
    the world frame p and v are the state's. Both are linear in the state vector of `StateEncoder`, whose
    layout is [p / s_p (0:3), v / s_v (3:6), q (6:10), goal / s_p (10:13)]. The network then learns only the
    departure from this extrapolation, and the start of every plan is anchored to the vehicle's own motion.
    """
    if num_ctrl_pts < 4:
        raise ValueError(f"the constant-velocity prior needs at least 4 control points, got {num_ctrl_pts}")
    if not horizon_s > 0.0:
        raise ValueError(f"horizon_s must be > 0, got {horizon_s}")
    dt = horizon_s / (num_ctrl_pts - 3)
    pts = torch.zeros(num_ctrl_pts, 3, STATE_DIM, dtype=torch.float64)  # P[i, axis] = sum_j m[i, axis, j] x_j
    for i in range(num_ctrl_pts):
        for axis in range(3):
            pts[i, axis, 3 + axis] = (i - 1) * dt * velocity_scale_mps
            if not local_frame:
                pts[i, axis, axis] = position_scale_m
    if polynomial:
        enc, _ = polynomial_maps(num_ctrl_pts, poly_degree)  # (D + 1, K)
        pts = torch.einsum("dk,kaj->daj", enc, pts)
    return pts.reshape(-1, STATE_DIM).to(torch.float32)


class OutputCodec(nn.Module):
    """Between world-frame control points (B, K, 3) and the network's flat output vector (B, out_dim).

    bspline: the K control points in the output frame, flattened point by point (x0, y0, z0, x1, ...).
    polynomial: the (degree+1) x 3 coefficient matrix of `polynomial_maps`, flattened row by row.
    The output frame is world (thesis) or local (yaw-only vehicle frame). The polynomial maps are applied in
    float64.
    """

    def __init__(self, num_ctrl_pts: int, local_frame: bool, polynomial: bool, poly_degree: int) -> None:
        super().__init__()
        self.num_ctrl_pts = int(num_ctrl_pts)
        self.local_frame = bool(local_frame)
        self.polynomial = bool(polynomial)
        if polynomial:
            enc, dec = polynomial_maps(num_ctrl_pts, poly_degree)
        else:
            enc, dec = (
                torch.zeros(0, num_ctrl_pts, dtype=torch.float64),
                torch.zeros(num_ctrl_pts, 0, dtype=torch.float64),
            )
        self.register_buffer("poly_encode", enc)
        self.register_buffer("poly_decode", dec)
        self.out_dim = int(3 * (poly_degree + 1 if polynomial else num_ctrl_pts))

    def encode(self, ctrl_world: Tensor, p_world_body: Tensor, q_world_body: Tensor) -> Tensor:
        pts = ctrl_world
        if self.local_frame:
            pts = world_to_local_points(pts, p_world_body, yaw_from_quaternion(q_world_body))
        if self.polynomial:
            pts = torch.matmul(self.poly_encode, pts.to(torch.float64)).to(torch.float32)
        return pts.reshape(pts.size(0), -1)

    def decode(self, y: Tensor, p_world_body: Tensor, q_world_body: Tensor) -> Tensor:
        if self.polynomial:
            pts = torch.matmul(self.poly_decode, y.reshape(y.size(0), -1, 3).to(torch.float64)).to(
                torch.float32
            )
        else:
            pts = y.reshape(y.size(0), self.num_ctrl_pts, 3)
        if self.local_frame:
            pts = local_to_world_points(pts, p_world_body, yaw_from_quaternion(q_world_body))
        return pts

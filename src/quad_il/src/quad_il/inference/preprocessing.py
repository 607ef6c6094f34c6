"""The exported policy's preprocessing and output decoding in Python: the training code itself
(learning/preprocessing.py: DepthPreprocessor, StateEncoder, OutputCodec) built from the parameters stored in
the exported file. The C++ twin is quad_policy/preprocessing.h; tests/python/test_inference_parity.py holds
both to the file's own methods and to each other."""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import NDArray

from quad_il.inference.meta import PolicyMeta
from quad_il.learning.preprocessing import DepthPreprocessor, OutputCodec, StateEncoder

FloatArray = NDArray[np.float64]


def as_row(values: NDArray[np.floating] | list[float], width: int, name: str) -> torch.Tensor:
    """(width,) numbers -> (1, width) float32 tensor; rejects wrong sizes and NaN/Inf naming the input."""
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.shape != (width,):
        raise ValueError(f"{name} must have {width} values, got shape {np.shape(values)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has a NaN/Inf element")
    return torch.from_numpy(a.astype(np.float32)).reshape(1, width)


class PolicyPreprocessing:
    """Depth, state and output transforms of one exported policy (inputs: one sample, numpy)."""

    def __init__(self, meta: PolicyMeta) -> None:
        self.meta = meta
        self.depth_pre = DepthPreprocessor(meta.input_height, meta.input_width, meta.max_depth_m)
        self.state_enc = StateEncoder(
            meta.state_frame == "local", meta.position_scale_m, meta.velocity_scale_mps, meta.velocity_input
        )
        self.codec = OutputCodec(
            meta.num_ctrl_pts,
            meta.output_frame == "local",
            meta.representation == "polynomial",
            max(meta.poly_degree, 1),
        )

    def depth(self, depth_m: NDArray[np.float32]) -> torch.Tensor:
        """(H, W) metres (REP 118) -> (1, 1, input_height, input_width) network input."""
        d = np.asarray(depth_m)
        if d.ndim != 2 or d.size == 0:
            raise ValueError(f"depth image must be a non-empty (H, W) array, got shape {d.shape}")
        d = np.ascontiguousarray(d, dtype=np.float32)
        if not d.flags.writeable:  # e.g. a view of a ROS message's buffer; torch wants writable memory
            d = d.copy()
        with torch.inference_mode():
            return self.depth_pre(torch.from_numpy(d).unsqueeze(0))

    def state(
        self,
        p_world_body: torch.Tensor,
        v_world: torch.Tensor,
        q_world_body: torch.Tensor,
        goal: torch.Tensor,
    ) -> torch.Tensor:
        """(1, 3), (1, 3), (1, 4) xyzw, (1, 3) float32 -> (1, 13) state vector."""
        if float(q_world_body.abs().sum()) == 0.0:
            raise ValueError("q_world_body is zero")
        with torch.inference_mode():
            return self.state_enc(p_world_body, v_world, q_world_body, goal)

    def decode(self, y: torch.Tensor, p_world_body: torch.Tensor, q_world_body: torch.Tensor) -> FloatArray:
        """Network output (1, output_dim) -> world-frame control points (K, 3) float64."""
        if y.numel() != self.meta.output_dim:
            raise ValueError(
                f"network output has {y.numel()} values, the policy declares {self.meta.output_dim}"
            )
        with torch.inference_mode():
            pts = self.codec.decode(y.reshape(1, -1), p_world_body, q_world_body)
        return pts[0].numpy().astype(np.float64)

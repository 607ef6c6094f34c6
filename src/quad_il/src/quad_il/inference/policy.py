"""An exported TorchScript policy (learning/export.py) run in Python: its preprocessing (the training code
itself, learning/preprocessing.py, built from the parameters stored in the file) and its forward pass. This
is all of inference that exists in Python too: the C++ node has its own (quad_policy/preprocessing.h,
torch_policy.h), and tests/python/test_inference_parity.py holds both to the file's own methods and to each
other. Everything after the network (decoding, safety layer, recovery, keeping) is the bound C++ decider."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from quad_il.inference.core import PolicyFormatError, PolicyMeta, parse_policy_meta
from quad_il.learning.export import load_exported
from quad_il.learning.preprocessing import DepthPreprocessor, StateEncoder


def configure_threads(num_threads: int) -> None:
    """torch intra-op threads of this process (inter-op: 1, if not yet set)."""
    if num_threads < 1:
        raise ValueError(f"num_threads must be >= 1, got {num_threads}")
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:
        pass  # already set: it may be set once, before any inter-op work
    torch.set_num_threads(num_threads)


def as_row(values: NDArray[np.floating] | list[float], width: int, name: str) -> torch.Tensor:
    """(width,) numbers -> (1, width) float32 tensor; rejects wrong sizes and NaN/Inf naming the input."""
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.shape != (width,):
        raise ValueError(f"{name} must have {width} values, got shape {np.shape(values)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has a NaN/Inf element")
    return torch.from_numpy(a.astype(np.float32)).reshape(1, width)


class LoadedPolicy:
    """The file, its metadata (the bound C++ parser) and the training preprocessing it was exported with.

    With `forward_net(depth_x, state_x)` in the file the state vector computed here is the network's input;
    otherwise (exports without that method) `forward_prepared(depth_x, p, v, q, goal)` encodes the state in
    the file. The C++ TorchPolicy makes the same choice."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        try:
            self.module, raw_meta = load_exported(path)
        except json.JSONDecodeError as e:
            raise PolicyFormatError(f"{self.path}: policy metadata is not valid JSON: {e}") from None
        except ValueError as e:
            raise PolicyFormatError(str(e)) from None
        except RuntimeError as e:
            # Truncated, or not a TorchScript archive at all (a text file, a zip of something else).
            raise PolicyFormatError(f"{self.path}: cannot load the TorchScript policy: {e}") from None
        self.meta: PolicyMeta = parse_policy_meta(json.dumps(raw_meta), self.path)
        m = self.meta
        for attr in ("input_height", "input_width", "max_depth_m", "num_ctrl_pts", "horizon_s"):
            if not hasattr(self.module, attr):
                raise PolicyFormatError(f"{self.path}: missing policy attribute {attr}")
            if getattr(self.module, attr) != getattr(m, attr):
                raise PolicyFormatError(
                    f"{self.path}: attribute {attr} = {getattr(self.module, attr)!r} disagrees with the "
                    f"metadata's {getattr(m, attr)!r}"
                )
        # Files from before multiple hypotheses have neither num_hypotheses nor mean_first: one plan.
        hypotheses = getattr(self.module, "num_hypotheses", 1)
        if hypotheses != m.hypotheses:
            raise PolicyFormatError(
                f"{self.path}: attribute num_hypotheses = {hypotheses!r} disagrees with the metadata's "
                f"output.hypotheses {m.hypotheses!r}"
            )
        mean_first = bool(getattr(self.module, "mean_first", False))
        if mean_first != m.mean_first:
            raise PolicyFormatError(
                f"{self.path}: attribute mean_first = {mean_first!r} disagrees with the metadata's "
                "output.hypotheses_first"
            )
        self.has_forward_net = hasattr(self.module, "forward_net")
        if not self.has_forward_net and not hasattr(self.module, "forward_prepared"):
            raise PolicyFormatError(f"{self.path}: the file has neither forward_net nor forward_prepared")
        self.depth_pre = DepthPreprocessor(m.input_height, m.input_width, m.max_depth_m)
        self.state_enc = StateEncoder(
            m.state_frame == "local", m.position_scale_m, m.velocity_scale_mps, m.velocity_input
        )

    def preprocess_depth(self, depth_m: NDArray[np.float32]) -> torch.Tensor:
        """(H, W) metres (REP 118) -> (1, 1, input_height, input_width) network input."""
        d = np.asarray(depth_m)
        if d.ndim != 2 or d.size == 0:
            raise ValueError(f"depth image must be a non-empty (H, W) array, got shape {d.shape}")
        d = np.array(d, dtype=np.float32, order="C")  # a copy: torch wants writable memory
        with torch.inference_mode():
            return self.depth_pre(torch.from_numpy(d).unsqueeze(0))

    def network_output(
        self, depth_x: torch.Tensor, p: NDArray, v: NDArray, q_xyzw: NDArray, goal: NDArray
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """The state vector (13,) and the flat network output (network_output_dim,) for a preprocessed depth
        frame and the odometry and goal (world frame)."""
        p_t, v_t = as_row(p, 3, "p_world_body"), as_row(v, 3, "v_world")
        q_t, g_t = as_row(q_xyzw, 4, "q_world_body"), as_row(goal, 3, "goal_world")
        if float(q_t.abs().sum()) == 0.0:
            raise ValueError("q_world_body is zero")
        with torch.inference_mode():
            state_x = self.state_enc(p_t, v_t, q_t, g_t)
            if self.has_forward_net:
                y = self.module.forward_net(depth_x, state_x)
            else:
                y = self.module.forward_prepared(depth_x, p_t, v_t, q_t, g_t)
        if y.numel() != self.meta.network_output_dim:
            raise RuntimeError(
                f"{self.path}: the network returned {y.numel()} values, the metadata declares "
                f"{self.meta.network_output_dim}"
            )
        return state_x.reshape(-1).numpy().copy(), y.reshape(-1).numpy().astype(np.float32)

    def warm_up(self, passes: int = 3) -> None:
        """The first forward passes of a TorchScript module are slower (profiling executor): run them before
        flying. PolicyFormatError naming the file when the forward pass fails (issue 30)."""
        x = torch.full((1, 1, self.meta.input_height, self.meta.input_width), 0.5)
        try:
            for _ in range(passes):
                self.network_output(x, np.zeros(3), np.zeros(3), np.array([0, 0, 0, 1.0]), np.ones(3))
        except RuntimeError as e:
            raise PolicyFormatError(
                f"{self.path}: the policy's forward pass fails on a test input: {e}"
            ) from None

    def decide(self, decider, stamp_s: float, depth_m, camera, p, v, q_xyzw, goal):
        """One decision of the bound C++ decider (a quad_policy_py.PolicyDecider built with this policy's
        meta) on this policy's Python forward pass: the network is asked for the goal, and again for each
        turned goal the recovery tries. Returns (decision, preprocess_ms, forward_ms) (the forward passes of
        the recovery are in the decision's safety time, as in C++)."""
        t0 = time.perf_counter()
        depth_x = self.preprocess_depth(depth_m)
        t1 = time.perf_counter()
        _, y = self.network_output(depth_x, p, v, q_xyzw, goal)
        t2 = time.perf_counter()
        d = decider.decide(
            stamp_s, depth_m, camera, p, v, q_xyzw, goal, y,
            lambda turned: self.network_output(depth_x, p, v, q_xyzw, turned)[1],
        )  # fmt: skip
        return d, 1e3 * (t1 - t0), 1e3 * (t2 - t1)

    # The file's own preprocessing and end-to-end forward (references for the parity tests).
    def file_preprocess_depth(self, depth_m: NDArray[np.float32]) -> NDArray[np.float32]:
        with torch.inference_mode():
            x = self.module.preprocess_depth(torch.from_numpy(np.array(depth_m, np.float32))[None])
        return x[0, 0].numpy().copy()

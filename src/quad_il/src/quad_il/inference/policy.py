"""An exported TorchScript policy (learning/export.py) loaded for inference."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from quad_il.inference.meta import PolicyFormatError, PolicyMeta, parse_policy_meta
from quad_il.learning.export import load_exported


def configure_threads(num_threads: int) -> None:
    """torch intra-op threads of this process (inter-op: 1, if not yet set)."""
    if num_threads < 1:
        raise ValueError(f"num_threads must be >= 1, got {num_threads}")
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:
        pass  # already set: it may be set once, before any inter-op work
    torch.set_num_threads(num_threads)


class LoadedPolicy:
    """The file and its metadata; `run` is the network alone (preprocessed depth + state -> flat output).

    With `forward_net(depth_x, state_x)` in the file the state vector computed here is the network's input;
    otherwise (exports without that method) `forward_prepared(depth_x, p, v, q, goal)` encodes the state in
    the file. The C++ TorchPolicy makes the same choice.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        try:
            self.module, self.raw_meta = load_exported(path)
        except json.JSONDecodeError as e:
            raise PolicyFormatError(f"{self.path}: policy metadata is not valid JSON: {e}") from None
        except ValueError as e:
            raise PolicyFormatError(str(e)) from None
        except RuntimeError as e:
            # Truncated, or not a TorchScript archive at all (a text file, a zip of something else).
            raise PolicyFormatError(f"{self.path}: cannot load the TorchScript policy: {e}") from None
        if not isinstance(self.raw_meta, dict):
            raise PolicyFormatError(f"{self.path}: policy metadata must be a JSON object")
        self.meta: PolicyMeta = parse_policy_meta(self.raw_meta, self.path)
        m = self.meta
        for attr, value in [
            ("input_height", m.input_height),
            ("input_width", m.input_width),
            ("max_depth_m", m.max_depth_m),
            ("num_ctrl_pts", m.num_ctrl_pts),
            ("horizon_s", m.horizon_s),
        ]:
            if not hasattr(self.module, attr):
                raise PolicyFormatError(f"{self.path}: missing policy attribute {attr}")
            file_value = getattr(self.module, attr)
            if file_value != value:
                raise PolicyFormatError(
                    f"{self.path}: attribute {attr} = {file_value!r} disagrees with the metadata's {value!r}"
                )
        # Files from before multiple hypotheses have no such attribute: one plan.
        file_hypotheses = getattr(self.module, "num_hypotheses", 1)
        if file_hypotheses != m.hypotheses:
            raise PolicyFormatError(
                f"{self.path}: attribute num_hypotheses = {file_hypotheses!r} disagrees with the metadata's "
                f"output.hypotheses {m.hypotheses!r}"
            )
        file_mean_first = bool(getattr(self.module, "mean_first", False))
        if file_mean_first != m.mean_first:
            raise PolicyFormatError(
                f"{self.path}: attribute mean_first = {file_mean_first!r} disagrees with the metadata's "
                f"output.hypotheses_first"
            )
        self.has_forward_net = hasattr(self.module, "forward_net")
        if not self.has_forward_net and not hasattr(self.module, "forward_prepared"):
            raise PolicyFormatError(f"{self.path}: the file has neither forward_net nor forward_prepared")

    def run(
        self,
        depth_x: torch.Tensor,
        state_x: torch.Tensor,
        p: torch.Tensor,
        v: torch.Tensor,
        q: torch.Tensor,
        goal: torch.Tensor,
    ) -> torch.Tensor:
        """(1, 1, h, w) and (1, 13) [+ raw (1, 3), (1, 3), (1, 4), (1, 3)] -> (1, network_output_dim)
        float32: one plan, or M plans and M confidence logits (`ordered_plans`)."""
        with torch.inference_mode():
            if self.has_forward_net:
                y = self.module.forward_net(depth_x, state_x)
            else:
                y = self.module.forward_prepared(depth_x, p, v, q, goal)
        if y.numel() != self.meta.network_output_dim:
            raise RuntimeError(
                f"{self.path}: the network returned {y.numel()} values, the metadata declares "
                f"{self.meta.network_output_dim}"
            )
        return y.reshape(1, -1)

    # The file's own preprocessing, decoding, selection and end-to-end forward (references for the parity
    # tests).
    def file_select(self, y: torch.Tensor) -> torch.Tensor:
        """The file's choice of the plan flown, (1, output_dim); files from before hypotheses: y itself."""
        if not hasattr(self.module, "select"):
            return y
        with torch.inference_mode():
            return self.module.select(y)

    def file_preprocess_depth(self, depth_m: NDArray[np.float32]) -> NDArray[np.float32]:
        with torch.inference_mode():
            x = self.module.preprocess_depth(
                torch.from_numpy(np.ascontiguousarray(depth_m, np.float32))[None]
            )
        return x[0, 0].numpy().copy()

    def file_decode(self, y: torch.Tensor, p: torch.Tensor, q: torch.Tensor) -> NDArray[np.float64]:
        with torch.inference_mode():
            return self.module.decode(y, p, q)[0].numpy().astype(np.float64)

    def file_forward(
        self,
        depth_m: NDArray[np.float32],
        p: torch.Tensor,
        v: torch.Tensor,
        q: torch.Tensor,
        goal: torch.Tensor,
    ) -> NDArray[np.float64]:
        with torch.inference_mode():
            d = torch.from_numpy(np.ascontiguousarray(depth_m, np.float32))[None]
            return self.module(d, p, v, q, goal)[0].numpy().astype(np.float64)


def ordered_plans(y: torch.Tensor, meta: PolicyMeta) -> list[tuple[int, torch.Tensor]]:
    """The network's output (1, network_output_dim) -> [(hypothesis index, plan (1, output_dim)), ...], most
    confident first (largest logit; equal logits in index order, as the file's `select`; NaN logits last);
    with `meta.mean_first` plan 0 first and the others after it in that order. One plan: [(0, y)]. The C++
    OrderedPlans makes the same order."""
    d, m = meta.output_dim, meta.hypotheses
    flat = y.reshape(-1)
    if flat.numel() != meta.network_output_dim:
        raise RuntimeError(
            f"network output has {flat.numel()} values, the policy declares {meta.network_output_dim}"
        )
    if m == 1:
        return [(0, flat.reshape(1, -1))]
    logits = [float(v) for v in flat[m * d :]]
    first = 1 if meta.mean_first else 0
    order = list(range(first)) + sorted(
        range(first, m), key=lambda i: (math.inf if math.isnan(logits[i]) else -logits[i], i)
    )
    return [(i, flat[i * d : (i + 1) * d].reshape(1, -1)) for i in order]

"""The depth-sensitivity diagnostic (quad_il.learning.depth_sensitivity) on constructed cases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor

from quad_il.inference.random_policy import GoalLinePolicy, export_goal_line_policy
from quad_il.learning.config import ModelConfig
from quad_il.learning.depth_sensitivity import angle_diff_deg, end_direction_deg, main, measure, rms_distance
from quad_il.learning.export import export_policy_file, seeded_check_inputs
from quad_il.learning.synthetic import write_synthetic_npz


class _DepthShift(GoalLinePolicy):
    """Test double: the goal line shifted sideways (world y) by the mean of the network's depth input, so the
    plan depends on the depth frame (a randomly initialised network barely does: its backbone's output is
    about 1e-10)."""

    @torch.jit.export
    def forward_prepared(
        self, depth_x: Tensor, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        ctrl = self.goal_line(p_world_body, goal_world)
        shift = depth_x.mean(dim=(1, 2, 3)).view(-1, 1) * torch.tensor([0.0, 2.0, 0.0], dtype=ctrl.dtype)
        return self.codec.encode(ctrl + shift.unsqueeze(1), p_world_body, q_world_body)


def _export_depth_shift(path: Path) -> Path:
    cfg = ModelConfig(input_height=32, input_width=32)
    policy = _DepthShift(cfg, 10, 2.0, 1.5).eval()
    return export_policy_file(
        policy, cfg, path, {"name": "depth_shift_test_double"}, seeded_check_inputs(cfg, 1, 11.0)
    )


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("ds")
    return write_synthetic_npz(
        d / "held_out.npz", num_episodes=3, samples_per_episode=8, height=48, width=64, seed=5
    )


def test_helpers_on_hand_made_plans() -> None:
    a = np.zeros((2, 4, 3))
    b = a.copy()
    b[:, :, 0] = 2.0
    assert rms_distance(a, b) == pytest.approx(2.0)
    plans = np.zeros((2, 3, 3))
    plans[0, -1, :2] = [1.0, 1.0]  # 45 deg
    plans[1, -1, :2] = [-1.0, -0.0001]  # just under -180 deg
    np.testing.assert_allclose(end_direction_deg(plans), [45.0, -179.994], atol=1e-3)
    assert angle_diff_deg(np.array([179.0]), np.array([-179.0]))[0] == pytest.approx(2.0)


def test_a_policy_that_ignores_depth_shows_none_and_one_that_reads_it_some(
    tmp_path: Path, data: Path
) -> None:
    blind = measure(export_goal_line_policy(tmp_path / "blind.ts"), [data], samples=20)
    assert blind.samples == 20
    assert blind.rms_real_vs_empty_m == 0.0 and blind.rms_real_vs_other_m == 0.0
    assert blind.end_dir_real_vs_empty_deg == 0.0 and blind.rms_policy_expert_m > 0.0
    net = measure(_export_depth_shift(tmp_path / "shift.ts"), [data])
    assert net.samples == 24  # all of them: fewer than asked
    assert net.rms_real_vs_empty_m > 0.0 and net.rms_real_vs_other_m > 0.0


def test_bad_input_is_named(tmp_path: Path, data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--policy", str(tmp_path / "none.ts"), "--data", str(data)]) == 2
    assert "--policy: no such file or directory" in capsys.readouterr().err
    policy = export_goal_line_policy(tmp_path / "blind.ts")
    assert main(["--policy", str(policy), "--data", str(tmp_path / "nothing")]) == 2
    assert "depth_sensitivity: " in capsys.readouterr().err
    assert main(["--policy", str(policy), "--data", str(data), "--samples", "1"]) == 2
    assert "--samples must be at least 2" in capsys.readouterr().err
    assert main(["--policy", str(policy), "--data", str(data), "--samples", "10"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("| quantity (10 samples) | value |") and "0.00 m" in out

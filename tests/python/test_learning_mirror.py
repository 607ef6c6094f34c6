"""Mirror augmentation (data.mirror_probability, quad_il.learning.preprocessing.mirror_about_heading): the
mirrored world seen from the mirrored vehicle is the original depth image flipped left to right; mirroring
twice gives the sample back; the trainer feeds the selected samples mirrored, with their mirrored targets,
chosen by (seed, epoch, sample) only."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from test_learning_training import dataset, tiny_config  # noqa: F401 (the dataset fixture)

from quad_il.learning.config import ConfigError, ModelConfig
from quad_il.learning.model import Policy
from quad_il.learning.preprocessing import mirror_about_heading, yaw_from_quaternion
from quad_il.learning.trainer import Trainer

R_BODY_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical frame in base_link
T_BODY_CAMERA = np.array([0.1, 0.0, 0.0])  # the simulator's mount: on the body's x axis


def _sample(rng: np.random.Generator):
    """A random attitude (any yaw, roll and pitch up to 17 deg), state, goal and points in front."""
    r = Rotation.from_euler(
        "ZYX", [rng.uniform(-np.pi, np.pi), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)]
    )
    p = torch.tensor(rng.normal(size=(1, 3)) + [0.0, 0.0, 1.5])
    q = torch.tensor(r.as_quat()[None])
    v = torch.tensor(rng.normal(size=(1, 3)))
    goal = torch.tensor(rng.normal(size=(1, 3)) * 10.0)
    pts = torch.tensor((p.numpy()[0] + r.apply([4.0, 0.0, 0.0]) + rng.normal(size=(6, 3)))[None])
    return p, v, q, goal, pts


def _camera_coordinates(p: torch.Tensor, q: torch.Tensor, pts: torch.Tensor) -> np.ndarray:
    r = Rotation.from_quat(q[0].numpy()).as_matrix()
    c = p[0].numpy() + r @ T_BODY_CAMERA
    return (pts[0].numpy() - c) @ (r @ R_BODY_CAMERA)  # rows: R_wc^T (X - c)


@pytest.mark.parametrize("seed", range(5))
def test_the_mirrored_world_seen_from_the_mirrored_vehicle_is_the_flipped_image(seed: int) -> None:
    p, v, q, goal, pts = _sample(np.random.default_rng(seed))
    v_m, q_m, goal_m, pts_m = mirror_about_heading(p, v, q, goal, pts)
    a = _camera_coordinates(p, q, pts)
    b = _camera_coordinates(p, q_m, pts_m)
    np.testing.assert_allclose(b[:, 0], -a[:, 0], atol=1e-12)  # image x flipped about the principal point
    np.testing.assert_allclose(b[:, 1:], a[:, 1:], atol=1e-12)  # rows and depth kept
    assert float(yaw_from_quaternion(q_m) - yaw_from_quaternion(q)) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(torch.linalg.vector_norm(q_m, dim=1).numpy(), [1.0], atol=1e-12)
    # Speed, distance to the goal and height are kept; mirroring twice gives the sample back.
    assert float(v_m.norm()) == pytest.approx(float(v.norm()))
    assert float((goal_m - p).norm()) == pytest.approx(float((goal - p).norm()))
    assert float(goal_m[0, 2]) == pytest.approx(float(goal[0, 2]))
    v2, q2, goal2, pts2 = mirror_about_heading(p, v_m, q_m, goal_m, pts_m)
    for x, y in ((v2, v), (q2, q), (goal2, goal), (pts2, pts)):
        np.testing.assert_allclose(x.numpy(), y.numpy(), atol=1e-12)
    assert mirror_about_heading(p, v, q, goal)[3] is None


def test_in_the_local_frame_the_mirror_negates_the_lateral_components() -> None:
    """The state and plan the network sees (local frame): lateral velocity, goal, plan negated."""
    p, v, q, goal, pts = _sample(np.random.default_rng(7))
    policy = Policy(
        ModelConfig(state_frame="local", output_frame="local", input_height=32, input_width=32), 6, 2.0
    )
    v_m, q_m, goal_m, pts_m = mirror_about_heading(p, v, q, goal, pts)
    s = policy.state_enc(p, v, q, goal)
    s_m = policy.state_enc(p, v_m, q_m, goal_m)
    flip = torch.tensor([1, 1, 1, 1, -1, 1, -1, 1, -1, 1, 1, -1, 1], dtype=s.dtype)  # z, v, q_local, goal
    np.testing.assert_allclose(s_m.numpy(), (s * flip).numpy(), atol=1e-12)
    y = policy.encode_target(pts, p, q).reshape(1, -1, 3)
    y_m = policy.encode_target(pts_m, p, q_m).reshape(1, -1, 3)
    np.testing.assert_allclose(
        y_m.numpy(), (y * torch.tensor([1.0, -1.0, 1.0], dtype=y.dtype)).numpy(), atol=1e-12
    )


def test_the_trainer_feeds_the_chosen_samples_mirrored(dataset, tmp_path) -> None:  # noqa: F811
    trainer = Trainer(tiny_config(dataset, tmp_path, "mirror", "data.mirror_probability=0.5"))
    mask = trainer._mirror_mask(1)
    assert mask is not None and 0 < int(mask.sum()) < len(mask)
    np.testing.assert_array_equal(mask, trainer._mirror_mask(1))  # a function of (seed, epoch, sample)
    assert not np.array_equal(mask, trainer._mirror_mask(2))
    batch = next(iter(trainer.train_loader.epoch(1)))
    out = trainer._mirrored(batch, mask)
    sel = mask[batch.indices]
    assert sel.any() and (~sel).any()
    idx = torch.from_numpy(batch.indices)
    for i, m in enumerate(sel):
        if m:
            torch.testing.assert_close(out.depth_x[i], batch.depth_x[i].flip(-1))
            torch.testing.assert_close(out.target[i], trainer.mirrored_targets[idx[i]])
            assert not torch.equal(out.v_world[i], batch.v_world[i])
        else:
            for name in ("depth_x", "v_world", "q_world_body", "goal_world", "target"):
                assert torch.equal(getattr(out, name)[i], getattr(batch, name)[i]), name
    torch.testing.assert_close(out.p_world_body, batch.p_world_body)
    # The mirrored targets are the targets of the mirrored plans: training on them trains.
    assert np.isfinite(trainer.fit().best_val_loss)


def test_off_by_default_and_bad_probabilities_name_the_key(dataset, tmp_path) -> None:  # noqa: F811
    trainer = Trainer(tiny_config(dataset, tmp_path, "plain"))
    assert trainer._mirror_mask(1) is None and trainer.mirrored_targets is None
    with pytest.raises(ConfigError, match=r"data\.mirror_probability"):
        tiny_config(dataset, tmp_path, "bad", "data.mirror_probability=1.5")

"""Policy network: MobileNetV3 backbone vs torchvision, sub-network shapes and sizes, preprocessing, frames,
output codecs and the TorchScript export (issue 7, "Must show (tests)")."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from quad_il.learning.config import ModelConfig, load_config
from quad_il.learning.export import (
    META_FILE,
    export_torchscript,
    fold_backbone_head,
    inference_module,
    load_exported,
    policy_metadata,
)
from quad_il.learning.mobilenet_v3 import MobileNetV3, adapt_stem_channels, count_parameters
from quad_il.learning.model import Policy, PolicyNet, build_policy, head_output_dim, mlp
from quad_il.learning.preprocessing import (
    DepthPreprocessor,
    OutputCodec,
    StateEncoder,
    constant_velocity_prior,
    local_to_world_points,
    polynomial_maps,
    uniform_cubic_basis,
    world_to_local_points,
    yaw_from_quaternion,
)

# TorchScript is deprecated in torch 2.13 but is LibTorch's loading path (export.py): expected warnings.
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
DATA = Path(__file__).resolve().parent / "data"
# torchvision's published parameter counts (3-channel input, 1000 ImageNet classes).
TORCHVISION_PARAMS = {"small": 2_542_856, "large": 5_483_032}


def read_torchvision_keys(variant: str) -> list[tuple[str, tuple[int, ...], str]]:
    """Keys/shapes/dtypes listed by running torchvision's own mobilenet_v3_<variant>() (fixture file)."""
    out = []
    for line in (DATA / f"torchvision_mobilenet_v3_{variant}_keys.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        key, shape, dtype = line.split()
        out.append((key, () if shape == "-" else tuple(int(s) for s in shape.split("x")), dtype))
    return out


def yaw_quat(yaw: float) -> torch.Tensor:
    return torch.tensor([[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]])


# --------------------------------------------------------------------------------------------------- backbone
@pytest.mark.parametrize("variant", ["small", "large"])
def test_backbone_parameter_count_equals_torchvision_published(variant: str) -> None:
    assert count_parameters(MobileNetV3(variant, in_channels=3)) == TORCHVISION_PARAMS[variant]
    # One depth channel: the stem conv (16 filters of 3x3) loses two input channels.
    assert (
        count_parameters(MobileNetV3(variant, in_channels=1)) == TORCHVISION_PARAMS[variant] - 2 * 16 * 3 * 3
    )


@pytest.mark.parametrize("variant", ["small", "large"])
def test_backbone_state_dict_has_torchvision_keys_shapes_and_dtypes(variant: str) -> None:
    ours = MobileNetV3(variant, in_channels=3).state_dict()
    expected = read_torchvision_keys(variant)
    assert list(ours) == [k for k, _, _ in expected]
    for key, shape, dtype in expected:
        assert tuple(ours[key].shape) == shape, key
        assert str(ours[key].dtype) == f"torch.{dtype}", key


@pytest.mark.parametrize("variant", ["small", "large"])
def test_torchvision_named_state_dict_loads_into_depth_backbone(variant: str) -> None:
    gen = torch.Generator().manual_seed(3)
    state = {}
    for key, shape, dtype in read_torchvision_keys(variant):
        if dtype == "int64":
            state[key] = torch.tensor(7)
        elif key.endswith("running_var"):
            state[key] = torch.rand(shape, generator=gen) + 0.5
        else:
            state[key] = torch.randn(shape, generator=gen) * 0.1
    net = MobileNetV3(variant, in_channels=1)
    net.load_torchvision_state_dict(state)
    own = net.state_dict()
    assert torch.equal(own["features.0.0.weight"], state["features.0.0.weight"].sum(dim=1, keepdim=True))
    for key in ("features.3.block.1.0.weight", "classifier.3.bias", "features.0.1.running_var"):
        assert torch.equal(own[key], state[key]), key


def test_one_channel_backbone_from_rgb_weights_matches_rgb_net_on_grey_images() -> None:
    torch.manual_seed(0)
    rgb = MobileNetV3("small", in_channels=3).eval()
    for m in rgb.modules():  # non-trivial BatchNorm statistics
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.3, 0.3)
            m.running_var.uniform_(0.5, 2.0)
    depth_net = MobileNetV3("small", in_channels=1).eval()
    depth_net.load_torchvision_state_dict(rgb.state_dict())
    grey = torch.rand(2, 1, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(depth_net(grey), rgb(grey.repeat(1, 3, 1, 1)), atol=1e-5, rtol=1e-5)


def test_stem_adaptation_to_several_channels_keeps_constant_input_response() -> None:
    w = torch.randn(16, 3, 3, 3)
    w2 = adapt_stem_channels(w, 2)
    assert w2.shape == (16, 2, 3, 3)
    torch.testing.assert_close(w2.sum(dim=1), w.sum(dim=1))


def test_mismatching_state_dict_is_rejected_naming_the_keys() -> None:
    net = MobileNetV3("small", in_channels=1)
    state = MobileNetV3("large", in_channels=3).state_dict()
    with pytest.raises(ValueError, match=r"missing keys .*unexpected keys|shapes do not match"):
        net.load_torchvision_state_dict(state)
    state = MobileNetV3("small", in_channels=3).state_dict()
    del state["features.5.block.2.fc1.weight"]
    with pytest.raises(ValueError, match="features.5.block.2.fc1.weight"):
        net.load_torchvision_state_dict(state)


def test_classifier_can_be_skipped_for_another_output_width() -> None:
    net = MobileNetV3("small", in_channels=1, num_classes=256)
    net.load_torchvision_state_dict(MobileNetV3("small", in_channels=3).state_dict(), load_classifier=False)
    assert net(torch.rand(2, 1, 32, 32)).shape == (2, 256)


def test_build_policy_loads_backbone_weights_file(tmp_path: Path) -> None:
    torch.manual_seed(1)
    src = MobileNetV3("small", in_channels=3)
    path = tmp_path / "mobilenet_v3_small.pth"
    torch.save(src.state_dict(), path)
    policy = build_policy(ModelConfig(input_height=32, input_width=32, backbone_weights=str(path)), 10, 2.0)
    torch.testing.assert_close(
        policy.net.backbone.state_dict()["classifier.0.weight"], src.classifier[0].weight
    )


# ----------------------------------------------------------------------------------------------- sub-networks
def linear_params(widths: list[int]) -> int:
    return sum(a * b + b for a, b in zip(widths[:-1], widths[1:], strict=True))


def test_thesis_mlps_have_hand_computed_shapes_and_parameter_counts() -> None:
    net = PolicyNet("small", out_dim=30)
    assert count_parameters(net.depth_mlp) == linear_params([1000, 128, 64, 32]) == 138_464
    assert count_parameters(net.state_mlp) == linear_params([13, 64, 32, 32]) == 4_032
    assert count_parameters(net.planning_mlp) == linear_params([64, 64, 128, 128]) == 28_992
    assert count_parameters(net.head) == 128 * 30 + 30
    total = 2_542_856 - 2 * 16 * 9 + 138_464 + 4_032 + 28_992 + 3_870
    assert count_parameters(net) == total
    relus = [m for m in net.depth_mlp if isinstance(m, torch.nn.ReLU)]
    assert len(relus) == 3 and len([m for m in net.planning_mlp if isinstance(m, torch.nn.ReLU)]) == 3
    b = 2
    x = torch.rand(b, 1, 32, 32)
    s = torch.rand(b, 13)
    with torch.no_grad():
        f_backbone = net.backbone(x)
        assert f_backbone.shape == (b, 1000)
        assert net.depth_mlp(f_backbone).shape == (b, 32)
        assert net.state_mlp(s).shape == (b, 32)
        assert net.planning_mlp(torch.rand(b, 64)).shape == (b, 128)
        assert net(x, s).shape == (b, 30)


def test_mlp_is_linear_relu_pairs() -> None:
    m = mlp(5, [4, 3])
    assert [type(x).__name__ for x in m] == ["Linear", "ReLU", "Linear", "ReLU"]
    assert (m(torch.randn(10, 5)) >= 0).all()


@pytest.mark.parametrize(
    ("output", "variant", "out_dim"),
    [("bspline", "small", 30), ("polynomial", "small", 18), ("bspline", "large", 30)],
)
def test_policy_maps_raw_inputs_to_world_control_points(output: str, variant: str, out_dim: int) -> None:
    torch.manual_seed(0)
    policy = build_policy(
        ModelConfig(variant=variant, input_height=32, input_width=32, output=output), 10, 2.0
    )
    assert policy.codec.out_dim == out_dim
    b = 3
    with torch.no_grad():
        out = policy.eval()(
            torch.rand(b, 45, 61) * 9,
            torch.rand(b, 3),
            torch.rand(b, 3),
            yaw_quat(0.3).repeat(b, 1),
            torch.rand(b, 3),
        )
    assert out.shape == (b, 10, 3) and out.dtype == torch.float32


def test_policy_rejects_mismatched_state_shapes() -> None:
    policy = build_policy(ModelConfig(input_height=32, input_width=32), 10, 2.0).eval()
    with pytest.raises(RuntimeError, match="q_world_body must be"):
        policy(torch.rand(2, 32, 32), torch.rand(2, 3), torch.rand(2, 3), torch.rand(2, 3), torch.rand(2, 3))


# ---------------------------------------------------------------------------------------------- preprocessing
def test_depth_preprocessing_is_block_mean_over_max_depth_with_no_return_as_max() -> None:
    pre = DepthPreprocessor(8, 8, max_depth_m=10.0)
    depth = torch.full((1, 16, 16), 2.0)
    depth[0, :2, :2] = torch.tensor(
        [[1.0, 3.0], [float("inf"), float("nan")]]
    )  # block mean (1+3+10+10)/4 = 6
    depth[0, 2:4, 0:2] = 25.0  # beyond range: clamped to 10
    depth[0, 4:6, 0:2] = -float("inf")  # -> 0
    before = depth.clone()
    x = pre(depth)
    assert torch.equal(depth.nan_to_num(), before.nan_to_num())  # the caller's image is not modified
    assert x.shape == (1, 1, 8, 8) and x.dtype == torch.float32
    assert x[0, 0, 0, 0].item() == pytest.approx(0.6, abs=2e-4)
    assert x[0, 0, 1, 0].item() == 1.0
    assert x[0, 0, 2, 0].item() == 0.0
    assert x[0, 0, 5, 5].item() == pytest.approx(0.2, abs=1e-4)
    assert torch.equal(x, x.half().float())  # float16-representable: the training cache is lossless


def test_depth_preprocessing_does_not_depend_on_batch_composition() -> None:
    pre = DepthPreprocessor(24, 32, 10.0)
    depth = torch.rand(5, 1, 75, 101) * 12
    together = pre(depth)
    alone = torch.cat([pre(depth[i : i + 1]) for i in range(5)])
    assert torch.equal(together, alone)


def test_world_local_round_trip_and_known_rotation() -> None:
    gen = torch.Generator().manual_seed(0)
    pts = torch.randn(4, 10, 3, generator=gen) * 5
    p = torch.randn(4, 3, generator=gen)
    yaw = torch.rand(4, generator=gen) * 6 - 3
    torch.testing.assert_close(local_to_world_points(world_to_local_points(pts, p, yaw), p, yaw), pts)
    # Vehicle at (1, 2, 3) facing +y (yaw 90 deg): the world point (1, 5, 4) is 3 m ahead, 1 m up.
    local = world_to_local_points(
        torch.tensor([[[1.0, 5.0, 4.0]]]),
        torch.tensor([[1.0, 2.0, 3.0]]),
        yaw_from_quaternion(yaw_quat(math.pi / 2)),
    )
    torch.testing.assert_close(local, torch.tensor([[[3.0, 0.0, 1.0]]]), atol=1e-6, rtol=0)


def test_local_state_encoding_on_a_hand_made_case() -> None:
    enc = StateEncoder(local_frame=True, position_scale_m=2.0, velocity_scale_mps=0.5)
    # Facing +y, flying +y at 1 m/s, goal 4 m ahead and 2 m to the left (-x in world).
    s = enc(
        torch.tensor([[1.0, 2.0, 3.0]]),
        torch.tensor([[0.0, 1.0, 0.0]]),
        -yaw_quat(math.pi / 2),
        torch.tensor([[-1.0, 6.0, 3.0]]),
    )
    expected = torch.tensor([[0, 0, 1.5, 2.0, 0, 0, 0, 0, 0, 1, 2.0, 1.0, 0]])
    torch.testing.assert_close(s, expected, atol=1e-6, rtol=0)
    world = StateEncoder(local_frame=False, position_scale_m=2.0, velocity_scale_mps=0.5)
    s = world(
        torch.tensor([[1.0, 2.0, 3.0]]),
        torch.tensor([[0.0, 1.0, 0.0]]),
        -yaw_quat(0.0),
        torch.tensor([[-1.0, 6.0, 3.0]]),
    )
    torch.testing.assert_close(s, torch.tensor([[0.5, 1, 1.5, 0, 2, 0, 0, 0, 0, 1, -0.5, 3, 1.5]]))


def test_local_state_keeps_roll_and_pitch_but_not_yaw() -> None:
    enc = StateEncoder(local_frame=True, position_scale_m=1.0, velocity_scale_mps=1.0)
    roll = 0.2
    q_roll = torch.tensor([[math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2)]])
    outs = []
    for yaw in (0.0, 1.0, -2.5):
        # q = q_yaw * q_roll (xyzw Hamilton product with a pure-z quaternion)
        cz, sz = math.cos(yaw / 2), math.sin(yaw / 2)
        x, _, _, w = q_roll[0].tolist()
        q = torch.tensor([[cz * x, sz * x, sz * w, cz * w]])
        outs.append(enc(torch.zeros(1, 3), torch.zeros(1, 3), q, torch.zeros(1, 3))[0, 6:10])
    for o in outs:
        torch.testing.assert_close(o, q_roll[0], atol=1e-6, rtol=0)


def test_bspline_codec_round_trips_in_both_frames() -> None:
    gen = torch.Generator().manual_seed(1)
    ctrl = torch.randn(3, 10, 3, generator=gen)
    p = torch.randn(3, 3, generator=gen)
    q = torch.nn.functional.normalize(torch.randn(3, 4, generator=gen), dim=1)
    for local in (False, True):
        codec = OutputCodec(10, local, polynomial=False, poly_degree=5)
        y = codec.encode(ctrl, p, q)
        assert y.shape == (3, 30)
        torch.testing.assert_close(codec.decode(y, p, q), ctrl, atol=1e-5, rtol=0)
    assert torch.equal(OutputCodec(10, False, False, 5).encode(ctrl, p, q), ctrl.reshape(3, 30))


def test_uniform_cubic_basis_reproduces_polynomials_and_matches_de_boor() -> None:
    a = uniform_cubic_basis(10, 57)
    assert a.shape == (57, 10)
    torch.testing.assert_close(a.sum(dim=1), torch.ones(57, dtype=torch.float64))  # partition of unity
    # Greville abscissae of knots (i - 3) dt: control points (i - 1) dt reproduce the line p(t) = t (dt = 1).
    greville = torch.arange(10, dtype=torch.float64) - 1.0
    torch.testing.assert_close(a @ greville, torch.linspace(0, 7, 57, dtype=torch.float64))
    # Hand-computed rows (57 samples over 7 segments: 8 per segment): at the domain start the basis is
    # (1, 4, 1) / 6 on the first three control points; half-way through segment 0, (1, 23, 23, 1) / 48.
    torch.testing.assert_close(a[0, :4], torch.tensor([1.0, 4.0, 1.0, 0.0], dtype=torch.float64) / 6.0)
    torch.testing.assert_close(a[4, :4], torch.tensor([1.0, 23.0, 23.0, 1.0], dtype=torch.float64) / 48.0)
    assert a[4, 4:].abs().max() == 0.0
    # ... and at the domain end the last three: (1, 4, 1) / 6.
    torch.testing.assert_close(a[-1, -4:], torch.tensor([0.0, 1.0, 4.0, 1.0], dtype=torch.float64) / 6.0)


def test_polynomial_codec_recovers_the_coefficients_of_a_cubic_trajectory() -> None:
    # p(tau) = C0 + C1 tau + C2 tau^2 + C3 tau^3 over tau in [-1, 1]; its exact B-spline control points are
    # the least-squares fit of dense samples (uniform cubic B-splines contain every cubic).
    coeffs = torch.tensor(
        [[1.0, -2.0, 0.5], [3.0, 0.0, 1.0], [-1.0, 4.0, 0.0], [0.5, -0.5, 0.2]], dtype=torch.float64
    )
    s = 16 * 7 + 1
    tau = torch.linspace(-1, 1, s, dtype=torch.float64)
    samples = (tau.unsqueeze(1) ** torch.arange(4, dtype=torch.float64)) @ coeffs
    a = uniform_cubic_basis(10, s)
    ctrl = torch.linalg.pinv(a) @ samples
    torch.testing.assert_close(a @ ctrl, samples)  # the cubic is exactly a B-spline
    for local in (False, True):
        codec = OutputCodec(10, local, polynomial=True, poly_degree=5)
        assert codec.out_dim == 18
        p, q = torch.tensor([[0.5, -1.0, 2.0]]), yaw_quat(0.7)
        world = ctrl.float().unsqueeze(0)
        if (
            local
        ):  # the polynomial lives in the output frame: place the trajectory so its local form is `ctrl`
            world = local_to_world_points(world, p, yaw_from_quaternion(q))
        y = codec.encode(world, p, q)
        expected = torch.cat([coeffs, torch.zeros(2, 3, dtype=torch.float64)]).float().reshape(1, -1)
        torch.testing.assert_close(y, expected, atol=1e-4, rtol=0)
        torch.testing.assert_close(codec.decode(y, p, q), world, atol=1e-4, rtol=0)


def test_polynomial_degree_is_validated() -> None:
    with pytest.raises(ValueError, match="poly_degree must be >= 1"):
        polynomial_maps(10, 0)
    with pytest.raises(ValueError, match="num_ctrl_pts >= 4"):
        uniform_cubic_basis(3, 10)


# ----------------------------------------------------------------------------------- constant-velocity prior
@pytest.mark.parametrize("frame", ["world", "local"])
@pytest.mark.parametrize("output", ["bspline", "polynomial"])
def test_constant_velocity_prior_decodes_to_the_straight_line_p_plus_t_v(frame: str, output: str) -> None:
    k, horizon = 10, 2.0
    gen = torch.Generator().manual_seed(3)
    b = 4
    p = torch.randn(b, 3, generator=gen) * 5
    v = torch.randn(b, 3, generator=gen) * 2
    q = torch.nn.functional.normalize(torch.randn(b, 4, generator=gen), dim=1)
    goal = torch.randn(b, 3, generator=gen) * 5
    local = frame == "local"
    enc = StateEncoder(local, 10.0, 3.0)
    m = constant_velocity_prior(k, horizon, local, output == "polynomial", 5, 10.0, 3.0)
    codec = OutputCodec(k, local, output == "polynomial", 5)
    assert m.shape == (codec.out_dim, 13)
    ctrl = codec.decode(enc(p, v, q, goal) @ m.t(), p, q).double()  # (B, K, 3) world
    s = 8 * (k - 3) + 1
    t = torch.linspace(0.0, horizon, s, dtype=torch.float64)
    samples = torch.einsum("sk,bkc->bsc", uniform_cubic_basis(k, s), ctrl)
    expected = p.double()[:, None, :] + t[None, :, None] * v.double()[:, None, :]
    torch.testing.assert_close(samples, expected, atol=2e-5, rtol=0)


def test_policy_with_prior_and_a_zero_head_flies_on_at_constant_velocity() -> None:
    torch.manual_seed(0)
    cfg = ModelConfig(
        input_height=32,
        input_width=32,
        state_frame="local",
        output_frame="local",
        output_prior="constant_velocity",
    )
    policy = build_policy(cfg, 10, 2.0).eval()
    with torch.no_grad():
        policy.net.head.weight.zero_()
        policy.net.head.bias.zero_()
        p, v = torch.tensor([[1.0, 2.0, 1.5]]), torch.tensor([[2.0, -1.0, 0.5]])
        out = policy(torch.rand(1, 32, 32) * 5, p, v, yaw_quat(0.7), torch.tensor([[9.0, 9.0, 1.0]]))
    dt = 2.0 / 7
    expected = torch.stack([p[0] + (i - 1) * dt * v[0] for i in range(10)])
    torch.testing.assert_close(out[0], expected, atol=1e-5, rtol=0)
    # Without the prior the same zero head outputs the vehicle's own position for every point.
    plain = build_policy(
        ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local"), 10, 2.0
    )
    assert not plain.net.prior.any()


def test_prior_needs_matching_state_and_output_frames() -> None:
    with pytest.raises(
        ValueError, match="model.output_prior: constant_velocity needs state_frame == output_frame"
    ):
        ModelConfig(state_frame="world", output_frame="local", output_prior="constant_velocity")
    with pytest.raises(ValueError, match="output_prior"):
        ModelConfig(output_prior="linear")


def test_prior_is_not_in_the_state_dict_so_older_checkpoints_load() -> None:
    cfg = ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local")
    old = build_policy(cfg, 10, 2.0).state_dict()
    assert not any(key.endswith("prior") for key in old)
    new = build_policy(cfg.model_copy(update={"output_prior": "constant_velocity"}), 10, 2.0)
    new.load_state_dict(old)  # strict: the same keys
    assert new.net.prior.abs().sum() > 0


def test_depth_grid_is_the_nearest_surface_per_cell_in_row_major_order() -> None:
    net = PolicyNet("small", out_dim=30, depth_grid=(2, 3))
    depth_x = torch.ones(2, 1, 8, 12)  # everything at max_depth_m: nearness 0
    depth_x[0, 0, 1, 5] = 0.25  # row cell 0, column cell 1 (columns 4-7)
    depth_x[0, 0, 2, 4] = 0.5  # the same cell, farther: the nearer one counts
    depth_x[0, 0, 7, 11] = 0.0  # row cell 1, column cell 2: a surface at the camera
    depth_x[1, 0, 4:, :4] = 0.75  # a whole cell of the second sample
    grid = net.grid_features(depth_x)
    expected = torch.tensor([[0.0, 0.75, 0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.25, 0.0, 0.0]])
    torch.testing.assert_close(grid, expected)


def test_depth_grid_feeds_the_planning_mlp_and_changes_the_plan() -> None:
    torch.manual_seed(0)
    plain = PolicyNet("small", out_dim=30)
    gridded = PolicyNet("small", out_dim=30, depth_grid=(8, 8))
    assert gridded.planning_mlp[0].in_features == plain.planning_mlp[0].in_features + 64 == 128
    gridded.eval()
    depth_x, state_x = torch.ones(1, 1, 96, 96), torch.zeros(1, 13)
    near = depth_x.clone()
    near[0, 0, 40:50, 40:50] = 0.1
    # Zero the backbone's path so that only the grid can see the box.
    for layer in gridded.depth_mlp.modules():
        if isinstance(layer, torch.nn.Linear):
            torch.nn.init.zeros_(layer.weight)
            torch.nn.init.zeros_(layer.bias)
    with torch.no_grad():
        assert not torch.allclose(gridded(near, state_x), gridded(depth_x, state_x))


def test_depth_grid_config_is_checked_with_a_clear_message() -> None:
    assert ModelConfig().depth_grid == []  # off by default: the thesis's network, older configs load
    for bad in ([8], [8, 8, 1], [0, 4], [4, 97]):
        with pytest.raises(ValueError, match=r"model.depth_grid must be \[\] or \[rows, cols\]"):
            ModelConfig(depth_grid=bad)
    with pytest.raises(ValueError, match="depth_grid must be"):
        PolicyNet("small", out_dim=30, depth_grid=(0, 3))


# ---------------------------------------------------------------------------------------- multiple hypotheses
def local_cfg(**kw: object) -> ModelConfig:
    """A small local-frame model configuration (32 x 32 input) with the given extra keys."""
    return ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local", **kw)


def test_hypotheses_head_gives_m_plans_and_m_logits() -> None:
    net = PolicyNet("small", out_dim=30, hypotheses=3)
    assert count_parameters(net.head) == 128 * 93 + 93  # 3 plans of 30 values + 3 logits
    assert head_output_dim(30, 1) == 30 and head_output_dim(30, 3) == 93
    with torch.no_grad():
        assert net(torch.rand(2, 1, 32, 32), torch.rand(2, 13)).shape == (2, 93)
    with pytest.raises(ValueError, match="hypotheses must be >= 1"):
        PolicyNet("small", out_dim=30, hypotheses=0)


def test_select_flies_the_plan_with_the_largest_logit_first_on_ties() -> None:
    policy = build_policy(local_cfg(hypotheses=3), 10, 2.0)
    d = policy.plan_dim
    plans = torch.arange(3 * d, dtype=torch.float32).reshape(1, 3, d).repeat(3, 1, 1)
    logits = torch.tensor([[0.1, 2.0, -1.0], [5.0, 5.0, 0.0], [-3.0, -2.0, -1.0]])
    y = torch.cat([plans.reshape(3, -1), logits], dim=1)
    got_plans, got_logits = policy.split_hypotheses(y)
    assert torch.equal(got_plans, plans) and torch.equal(got_logits, logits)
    chosen = policy.select(y)
    assert torch.equal(chosen[0], plans[0, 1]) and torch.equal(chosen[1], plans[0, 0])
    assert torch.equal(chosen[2], plans[0, 2])
    with pytest.raises(RuntimeError, match="head width"):
        policy.split_hypotheses(y[:, :-1])
    # forward decodes the selected plan.
    torch.manual_seed(1)
    inputs = (torch.rand(2, 40, 40) * 9, torch.rand(2, 3), torch.rand(2, 3), yaw_quat(0.4).repeat(2, 1))
    goal = torch.rand(2, 3) * 10
    with torch.no_grad():
        policy.eval()
        y = policy.forward_prepared(policy.preprocess_depth(inputs[0]), *inputs[1:], goal)
        expected = policy.decode(policy.select(y), inputs[1], inputs[3])
        torch.testing.assert_close(policy(*inputs, goal), expected)


def test_mean_first_flies_plan_0_whatever_the_logits() -> None:
    policy = build_policy(local_cfg(hypotheses=3, hypotheses_first="mean"), 10, 2.0)
    d = policy.plan_dim
    y = torch.cat(
        [torch.arange(3 * d, dtype=torch.float32).reshape(1, -1), torch.tensor([[-5.0, 9.0, 1.0]])], 1
    )
    assert torch.equal(policy.select(y), y[:, :d])
    with pytest.raises(ValueError, match="hypotheses_first: mean needs model.hypotheses >= 3"):
        ModelConfig(hypotheses=2, hypotheses_first="mean")
    with pytest.raises(ValueError, match="hypotheses_first"):
        ModelConfig(hypotheses=3, hypotheses_first="best")


def test_prior_is_added_to_every_hypothesis_and_not_to_the_logits() -> None:
    policy = build_policy(local_cfg(output_prior="constant_velocity", hypotheses=2), 10, 2.0).eval()
    with torch.no_grad():
        policy.net.head.weight.zero_()
        policy.net.head.bias.zero_()
        y = policy.forward_prepared(
            torch.rand(1, 1, 32, 32),
            torch.zeros(1, 3),
            torch.tensor([[2.0, 0, 0]]),
            yaw_quat(0.0),
            torch.tensor([[9.0, 0, 1.0]]),
        )
    plans, logits = policy.split_hypotheses(y)
    torch.testing.assert_close(plans[0, 0], plans[0, 1])
    assert plans.abs().sum() > 0 and not logits.any()


def test_hypotheses_config_is_checked_with_a_clear_message() -> None:
    assert ModelConfig().hypotheses == 1  # the thesis's single plan by default
    for bad in (0, 9):
        with pytest.raises(ValueError, match="hypotheses"):
            ModelConfig(hypotheses=bad)
    with pytest.raises(ValueError, match="eil scores one plan per row"):
        load_config([], ["model.hypotheses=3", "optim.loss=eil"])


# ------------------------------------------------------------------------------------------------ TorchScript
def make_backbone_head_matter(policy: Policy, seed: int) -> Policy:
    """A trained-like state for fold and export tests (eval mode on return).

    At initialisation the backbone's features are ~1e-10 in eval mode (unit running variances) and its last
    Linear is N(0, 0.01) with zero bias, so a wrong fold of that layer (`fold_backbone_head`) would not show
    in the outputs. Here the BatchNorm running statistics are set to the statistics of random batches and the
    backbone's last Linear and depth_mlp[0] get larger random weights and non-zero biases.
    """
    gen = torch.Generator().manual_seed(seed)
    h, w = policy.input_height, policy.input_width
    bns = [m for m in policy.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    for bn in bns:
        bn.reset_running_stats()
        bn.momentum = None  # cumulative average over the passes below
    policy.train()
    with torch.no_grad():
        for _ in range(3):
            policy.forward_prepared(
                torch.rand(8, 1, h, w, generator=gen),
                torch.randn(8, 3, generator=gen),
                torch.randn(8, 3, generator=gen),
                torch.nn.functional.normalize(torch.randn(8, 4, generator=gen), dim=1),
                torch.randn(8, 3, generator=gen),
            )
        for bn in bns:
            bn.momentum = 0.01
        last, first = policy.net.backbone.classifier[-1], policy.net.depth_mlp[0]
        last.weight.normal_(0.0, 0.05, generator=gen)
        last.bias.normal_(0.0, 0.5, generator=gen)
        first.weight.normal_(0.0, 0.05, generator=gen)
        first.bias.normal_(0.0, 0.2, generator=gen)
    return policy.eval()


def raw_inputs(b: int, h: int = 32, w: int = 32) -> tuple[torch.Tensor, ...]:
    """Policy.forward's inputs for b samples: depth (metres), p, v, a unit quaternion, goal (global RNG)."""
    return (
        torch.rand(b, h, w) * 5,
        torch.randn(b, 3),
        torch.randn(b, 3),
        torch.nn.functional.normalize(torch.randn(b, 4), dim=1),
        torch.randn(b, 3),
    )


def net_inputs(policy: Policy, b: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    depth_x = torch.rand(b, 1, policy.input_height, policy.input_width, generator=gen)
    return depth_x, torch.randn(b, 13, generator=gen)


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"variant": "large"},
        {"state_frame": "local", "output_frame": "local", "output": "polynomial", "poly_degree": 4},
        {"state_frame": "local", "output_frame": "local", "output_prior": "constant_velocity"},
        {"state_frame": "local", "output_frame": "local", "depth_grid": [4, 5]},
        {"state_frame": "local", "output_frame": "local", "hypotheses": 3},
        {"state_frame": "local", "output_frame": "local", "hypotheses": 4, "hypotheses_first": "mean"},
    ],
)
def test_torchscript_export_equals_eager_policy(tmp_path: Path, kw: dict[str, object]) -> None:
    torch.manual_seed(2)
    cfg = ModelConfig(input_height=32, input_width=40, max_depth_m=8.0, **kw)
    policy: Policy = make_backbone_head_matter(build_policy(cfg, 10, 2.0), seed=3)
    gen = torch.Generator().manual_seed(5)
    b = 6
    depth = torch.rand(b, 60, 80, generator=gen) * 12
    depth[0, :5, :5] = float("inf")
    inputs = (
        depth,
        torch.randn(b, 3, generator=gen) * 10,
        torch.randn(b, 3, generator=gen),
        torch.nn.functional.normalize(torch.randn(b, 4, generator=gen), dim=1),
        torch.randn(b, 3, generator=gen) * 10,
    )
    path = tmp_path / "policy.ts"
    meta = policy_metadata(policy, cfg.model_dump(mode="json"))
    diff = export_torchscript(policy, path, meta, check_inputs=inputs)
    assert diff <= 1e-4
    module, loaded_meta = load_exported(path)
    p, v, q, goal = inputs[1:]
    with torch.no_grad():
        torch.testing.assert_close(module(*inputs), policy(*inputs), atol=1e-5, rtol=1e-5)
        assert torch.equal(module.preprocess_depth(depth), policy.preprocess_depth(depth))
        depth_x = policy.preprocess_depth(depth)
        y = policy.forward_prepared(depth_x, p, v, q, goal)
        y_file = module.forward_prepared(depth_x, p, v, q, goal)
        assert float((y_file - y).abs().max()) <= 1e-4
        # Channels-last input (what a channels_last training loop would pass) gives the same.
        y_cl = module.forward_prepared(depth_x.contiguous(memory_format=torch.channels_last), p, v, q, goal)
        torch.testing.assert_close(y_cl, y_file, atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(module.select(y), policy.select(y))
        for file_part, part in zip(module.split_hypotheses(y), policy.split_hypotheses(y), strict=True):
            torch.testing.assert_close(file_part, part)
        ctrl = policy.decode(policy.select(y), p, q)
        torch.testing.assert_close(module.decode(policy.select(y), p, q), ctrl, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(module.encode_target(ctrl, p, q), policy.encode_target(ctrl, p, q))
    assert (module.input_height, module.input_width, module.max_depth_m) == (32, 40, 8.0)
    assert (module.num_ctrl_pts, module.horizon_s) == (10, 2.0)
    assert module.num_hypotheses == loaded_meta["output"]["hypotheses"] == kw.get("hypotheses", 1)
    assert loaded_meta["output"]["hypotheses_first"] == kw.get("hypotheses_first", "confidence")
    assert module.mean_first == (kw.get("hypotheses_first") == "mean")
    assert loaded_meta == json.loads(json.dumps(meta))
    assert loaded_meta["preprocessing"]["input_width"] == 40
    assert loaded_meta["preprocessing"]["state_frame"] == kw.get("state_frame", "world")
    assert loaded_meta["output"]["num_ctrl_pts"] == 10
    extra = {META_FILE: ""}
    torch.jit.load(str(path), _extra_files=extra)
    assert json.loads(extra[META_FILE])["format"] == "quad_il_policy/1"
    # The file holds the folded network: no 1000-wide layer, and channels_last convolution weights.
    consts = [
        n.output().toIValue()
        for n in module.forward_prepared.graph.nodes()
        if n.kind() == "prim::Constant" and n.output().type().kind() == "TensorType"
    ]
    assert not [t for t in consts if t.dim() == 2 and 1000 in t.shape]
    hidden = 1280 if kw.get("variant") == "large" else 1024
    assert [t for t in consts if t.dim() == 2 and tuple(t.shape) == (128, hidden)]
    convs = [t for t in consts if t.dim() == 4]
    assert convs and all(t.is_contiguous(memory_format=torch.channels_last) for t in convs)


def test_export_check_compares_with_the_eager_unfolded_policy(tmp_path: Path) -> None:
    """The check runs the reloaded file against the caller's policy, so a file that differs is refused."""
    torch.manual_seed(4)
    cfg = ModelConfig(input_height=32, input_width=32)
    policy = make_backbone_head_matter(build_policy(cfg, 10, 2.0), seed=4)
    inputs = raw_inputs(2)
    meta = policy_metadata(policy, cfg.model_dump(mode="json"))
    assert export_torchscript(policy, tmp_path / "ok.ts", meta, inputs) <= 1e-4
    with pytest.raises(RuntimeError, match="differs from the eager policy"):
        export_torchscript(policy, tmp_path / "strict.ts", meta, inputs, tol=-1.0)


@pytest.mark.parametrize(
    ("variant", "backbone_out", "hidden"),
    [("small", 1000, 1024), ("large", 1000, 1280), ("small", 256, 1024)],
)
def test_fold_backbone_head_equals_the_unfolded_network(variant: str, backbone_out: int, hidden: int) -> None:
    torch.manual_seed(6)
    cfg = ModelConfig(input_height=32, input_width=32, variant=variant, backbone_out=backbone_out)
    policy = make_backbone_head_matter(build_policy(cfg, 10, 2.0), seed=7)
    folded = fold_backbone_head(policy)
    assert folded is not policy and not folded.training
    assert isinstance(folded.net.backbone.classifier[-1], torch.nn.Identity)
    layer = folded.net.depth_mlp[0]
    assert isinstance(layer, torch.nn.Linear) and (layer.in_features, layer.out_features) == (hidden, 128)
    assert layer.weight.dtype == torch.float32
    last, first = policy.net.backbone.classifier[-1], policy.net.depth_mlp[0]
    w1, b1, w2, b2 = (t.detach().double() for t in (last.weight, last.bias, first.weight, first.bias))
    torch.testing.assert_close(layer.weight.detach().double(), w2 @ w1, atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(layer.bias.detach().double(), w2 @ b1 + b2, atol=1e-7, rtol=1e-6)
    depth_x, state_x = net_inputs(policy, 5, seed=8)
    with torch.no_grad():
        torch.testing.assert_close(
            folded.net(depth_x, state_x), policy.net(depth_x, state_x), atol=1e-5, rtol=0
        )
        # The backbone of the copy returns the classifier's hidden features; depth_mlp takes them.
        feats = folded.net.backbone(depth_x)
        assert feats.shape == (5, hidden)
        torch.testing.assert_close(
            folded.net.depth_mlp(feats), policy.net.depth_mlp(policy.net.backbone(depth_x)), atol=1e-5, rtol=0
        )
        # Guard for this test's weights: both parts of the folded bias and the folded weight matter.
        ref = policy.net(depth_x, state_x)
        for tensor in (last.bias, last.weight, first.bias):
            saved = tensor.clone()
            tensor.zero_()
            assert float((policy.net(depth_x, state_x) - ref).abs().max()) > 1e-3
            tensor.copy_(saved)


def test_fold_backbone_head_rejects_another_structure() -> None:
    cfg = ModelConfig(input_height=32, input_width=32)

    def fresh() -> Policy:
        torch.manual_seed(0)
        return build_policy(cfg, 10, 2.0)

    policy = fresh()
    policy.net.backbone.classifier[-1] = torch.nn.Identity()
    with pytest.raises(ValueError, match=r"classifier's last layer must be nn\.Linear, got Identity"):
        fold_backbone_head(policy)
    policy = fresh()
    policy.net.depth_mlp[0] = torch.nn.Identity()
    with pytest.raises(ValueError, match=r"depth_mlp\[0\] must be nn\.Linear, got Identity"):
        fold_backbone_head(policy)
    policy = fresh()
    policy.net.backbone.classifier[-1] = torch.nn.Linear(1024, 999)
    with pytest.raises(
        ValueError, match=r"depth_mlp\[0\] takes 1000 features but the backbone classifier gives 999"
    ):
        fold_backbone_head(policy)

    class OtherNet(PolicyNet):
        def forward(self, depth_x: torch.Tensor, state_x: torch.Tensor) -> torch.Tensor:
            return super().forward(depth_x.flip(-1), state_x)

    policy = fresh()
    policy.net.__class__ = OtherNet
    with pytest.raises(ValueError, match="policy.net must be a PolicyNet with its own forward, got OtherNet"):
        fold_backbone_head(policy)
    # export_torchscript refuses such a policy with the same message, before writing anything.
    with pytest.raises(ValueError, match="fold_backbone_head: policy.net must be a PolicyNet"):
        export_torchscript(policy, Path("/nonexistent/dir/p.ts"), {})


@pytest.mark.parametrize("memory_format", [torch.contiguous_format, torch.channels_last])
def test_export_leaves_the_callers_policy_untouched(
    tmp_path: Path, memory_format: torch.memory_format
) -> None:
    torch.manual_seed(9)
    cfg = ModelConfig(input_height=32, input_width=32)
    policy = make_backbone_head_matter(build_policy(cfg, 10, 2.0), seed=9).to(memory_format=memory_format)
    policy.train()  # as the trainer may leave it
    before = {k: (v.clone(), v.stride()) for k, v in policy.state_dict().items()}
    layers = (policy.net.backbone.classifier[-1], policy.net.depth_mlp[0])
    depth_x, state_x = net_inputs(policy, 3, seed=10)
    inputs = raw_inputs(3)
    export_torchscript(policy, tmp_path / "p.ts", policy_metadata(policy, {}), inputs)
    assert policy.training
    after = policy.state_dict()
    assert after.keys() == before.keys()
    for key, (value, stride) in before.items():
        assert torch.equal(after[key], value), key
        assert after[key].stride() == stride, key
    conv = policy.net.backbone.features[0][0].weight
    assert conv.is_contiguous(memory_format=memory_format)
    assert (policy.net.backbone.classifier[-1], policy.net.depth_mlp[0]) == layers
    assert (layers[0].out_features, layers[1].in_features) == (1000, 1000)
    assert all(p.requires_grad for p in policy.parameters())
    # inference_module (what is scripted) is a separate, folded, channels_last module.
    inf = inference_module(policy)
    assert inf.net.backbone.features[0][0].weight.is_contiguous(memory_format=torch.channels_last)
    assert isinstance(inf.net.backbone.classifier[-1], torch.nn.Identity)
    assert policy.net.backbone.classifier[-1] is layers[0] and policy.training
    with torch.no_grad():
        policy.eval()
        torch.testing.assert_close(inf.net(depth_x, state_x), policy.net(depth_x, state_x), atol=1e-5, rtol=0)


def test_loading_a_file_that_is_not_a_policy_export_fails_clearly(tmp_path: Path) -> None:
    path = tmp_path / "plain.ts"
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(path))
    with pytest.raises(ValueError, match="not a quad_il policy export"):
        load_exported(path)
    with pytest.raises(FileNotFoundError):
        load_exported(tmp_path / "missing.ts")


def test_network_output_is_deterministic_for_a_seed() -> None:
    outs = []
    for _ in range(2):
        torch.manual_seed(11)
        policy = build_policy(ModelConfig(input_height=32, input_width=32), 10, 2.0).eval()
        with torch.no_grad():
            outs.append(policy.net(torch.ones(1, 1, 32, 32), torch.ones(1, 13)))
    assert torch.equal(outs[0], outs[1])
    assert np.isfinite(outs[0].numpy()).all()


@pytest.mark.parametrize("local", [False, True])
def test_without_velocity_input_the_state_ignores_the_velocity(local: bool) -> None:
    gen = torch.Generator().manual_seed(4)
    p, goal = torch.randn(3, 3, generator=gen), torch.randn(3, 3, generator=gen)
    q = torch.nn.functional.normalize(torch.randn(3, 4, generator=gen), dim=1)
    v1, v2 = torch.randn(3, 3, generator=gen), torch.randn(3, 3, generator=gen)
    blind = StateEncoder(local, 10.0, 3.0, velocity_input=False)
    seeing = StateEncoder(local, 10.0, 3.0)
    assert torch.equal(blind(p, v1, q, goal), blind(p, v2, q, goal))
    assert not torch.equal(seeing(p, v1, q, goal), seeing(p, v2, q, goal))
    keep = [0, 1, 2, *range(6, 13)]  # everything but the velocity entries is unchanged
    torch.testing.assert_close(blind(p, v1, q, goal)[:, keep], seeing(p, v1, q, goal)[:, keep])
    assert not blind(p, v1, q, goal)[:, 3:6].any()
    with pytest.raises(ValueError, match="the constant-velocity prior needs model.velocity_input: true"):
        ModelConfig(
            state_frame="local", output_frame="local", output_prior="constant_velocity", velocity_input=False
        )

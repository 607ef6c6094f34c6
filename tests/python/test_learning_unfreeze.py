"""A training checkpoint rebuilt from an exported, frozen policy file (quad_il.learning.unfreeze)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch
import yaml
from torch import nn

from quad_il.learning.checkpoint import read_training_checkpoint
from quad_il.learning.config import TrainConfig
from quad_il.learning.export import export_policy_file, seeded_check_inputs
from quad_il.learning.model import Policy
from quad_il.learning.trainer import load_initial_weights
from quad_il.learning.unfreeze import UnfreezeError, main, recover_checkpoint, unfreeze

REPO = Path(__file__).resolve().parents[2]


def _trained_like_policy(cfg: TrainConfig, seed: int = 3) -> Policy:
    """A policy with non-trivial BatchNorm statistics and affine parameters, as a trained one has."""
    torch.manual_seed(seed)
    policy = Policy(cfg.model, 10, 1.5)
    with torch.no_grad():
        for m in policy.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.2, 2.0)
                m.weight.uniform_(-1.5, 1.5)  # negative scales too: the fold flips those channels
                m.bias.uniform_(-0.3, 0.3)
            elif isinstance(m, nn.Linear):
                m.bias.uniform_(-0.1, 0.1)
    return policy.eval()


def _config(tmp_path: Path, **model: object) -> tuple[TrainConfig, Path]:
    cfg = TrainConfig.model_validate(
        {
            "model": {
                "input_height": 32,
                "input_width": 32,
                "state_frame": "local",
                "output_frame": "local",
                **model,
            }
        }
    )
    path = tmp_path / "train_config.yaml"
    path.write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    return cfg, path


def _export(tmp_path: Path, cfg: TrainConfig, policy: Policy) -> Path:
    return export_policy_file(
        policy, cfg.model, tmp_path / "policy.ts", {"name": "t"}, seeded_check_inputs(cfg.model, 0)
    )


def test_the_rebuilt_policy_computes_what_the_file_computes_and_warm_starts_a_run(tmp_path: Path) -> None:
    cfg, cfg_path = _config(tmp_path)
    original = _trained_like_policy(cfg)
    ts = _export(tmp_path, cfg, original)
    sha = hashlib.sha256(ts.read_bytes()).hexdigest()
    card = f"# card\n`policy.ts`: sha256 `{sha}`\n\n## How it was made\n\n### `runs/a`\n"
    (tmp_path / "MODEL.md").write_text(card)
    summary = recover_checkpoint(ts, cfg_path, tmp_path / "ck" / "best.pt", command="unfreeze x")
    assert summary["max_abs_diff"] <= 1e-4
    ckpt = read_training_checkpoint(tmp_path / "ck" / "best.pt")
    origin = ckpt["unfrozen_from"]
    assert origin["sha256"] == summary["sha256"] == sha and origin["command"] == "unfreeze x"
    assert origin["model_card"] == "## How it was made\n\n### `runs/a`\n"  # the card beside the file
    fresh = Policy(cfg.model, 10, 1.5)
    load_initial_weights(fresh, tmp_path / "ck" / "best.pt", cfg.model)  # what run.init_weights does
    fresh.eval()
    inputs = seeded_check_inputs(cfg.model, 7)
    with torch.no_grad():
        assert torch.allclose(fresh(*inputs), original(*inputs), atol=1e-4)
        # the backbone's weights are the original's up to the BatchNorm fold, not a copy of the fold target
        assert not torch.equal(fresh.net.depth_mlp[0].weight, original.net.depth_mlp[0].weight)


def test_calibrated_batchnorms_compute_in_training_mode_about_what_they_compute_in_eval_mode(
    tmp_path: Path,
) -> None:
    cfg, _ = _config(tmp_path, backbone_dropout=0.0)
    original = _trained_like_policy(cfg)
    ts = _export(tmp_path, cfg, original)
    module = torch.jit.load(str(ts))
    torch.manual_seed(0)
    frames = torch.rand(64, 1, 32, 32)

    def backbone_gap(calib: torch.Tensor | None) -> float:
        torch.manual_seed(1)
        policy = Policy(cfg.model, 10, 1.5)
        unfreeze(module, policy, cfg.model, calib)
        with torch.no_grad():
            policy.eval()
            ref = policy.net.backbone(frames)
            policy.train()
            batch = policy.net.backbone(frames)
        return float((batch - ref).abs().max() / ref.abs().max())

    calibrated, uncalibrated = backbone_gap(frames), backbone_gap(None)
    assert calibrated < 1e-3  # the batch is the calibration set: its statistics are the running ones
    assert uncalibrated > 10 * calibrated  # without calibration a batch's statistics rescale every channel


def test_a_config_that_differs_from_the_file_is_refused_naming_the_keys(tmp_path: Path) -> None:
    cfg, _ = _config(tmp_path)
    ts = _export(tmp_path, cfg, _trained_like_policy(cfg))
    (tmp_path / "o").mkdir()
    _, other = _config(tmp_path / "o", depth_mlp=[128, 64, 16])
    with pytest.raises(UnfreezeError, match=r"model settings differ .*depth_mlp"):
        recover_checkpoint(ts, other, tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()


def test_bad_inputs_get_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg, cfg_path = _config(tmp_path)
    not_policy = tmp_path / "junk.ts"
    not_policy.write_bytes(b"not a policy")
    assert main([str(not_policy), "--config", str(cfg_path), "--out", str(tmp_path / "a.pt")]) == 2
    assert "junk.ts" in capsys.readouterr().err
    ts = _export(tmp_path, cfg, _trained_like_policy(cfg))
    bad_cfg = tmp_path / "bad.yaml"
    bad_cfg.write_text("model: {variant: huge}\n")
    assert main([str(ts), "--config", str(bad_cfg), "--out", str(tmp_path / "b.pt")]) == 2
    assert "not a training configuration" in capsys.readouterr().err
    empty = tmp_path / "empty_dataset"
    empty.mkdir()
    args = [str(ts), "--config", str(cfg_path), "--out", str(tmp_path / "c.pt"), "--calib", str(empty)]
    assert main(args) == 2
    assert "--calib" in capsys.readouterr().err


def test_the_shipped_policy_unfreezes_with_its_training_config(tmp_path: Path) -> None:
    model = REPO / "models" / "quad_il_policy"
    summary = recover_checkpoint(model / "policy.ts", model / "train_config.yaml", tmp_path / "best.pt")
    assert summary["max_abs_diff"] <= 1e-4


def test_calibration_frames_are_spread_over_every_shard(tmp_path: Path) -> None:
    from quad_il.data.postprocess import iter_shard_arrays
    from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
    from quad_il.learning.unfreeze import calibration_frames

    try:
        find_collector_tool("write_synthetic_dataset")
    except FileNotFoundError as e:
        pytest.skip(f"cpp_data_collector not built: {e}")
    data = write_synthetic_dataset(
        tmp_path / "d", seed=2, records=24, width=40, height=30, records_per_episode=8, shard_size_mb=0.05
    )
    cfg, _ = _config(tmp_path)
    policy = Policy(cfg.model, 10, 1.5)
    shards = [fixed.depth_m for _name, fixed in iter_shard_arrays(data)]
    assert len(shards) >= 3
    frames = calibration_frames(data, policy, 2 * len(shards))
    # two frames of each shard, its first and its last, in shard order
    want = torch.cat(
        [policy.depth_pre(torch.from_numpy(d[[0, len(d) - 1]].astype("float32"))) for d in shards]
    )
    assert torch.equal(frames, want)

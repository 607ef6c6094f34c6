"""Weight averaging (quad_il.learning.soup): the averaged weights, the exported file, and the errors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from test_learning_training import tiny_config

from quad_il.inference.policy import LoadedPolicy
from quad_il.learning.config import ModelConfig
from quad_il.learning.export import load_exported, seeded_check_inputs
from quad_il.learning.soup import SoupError, average_checkpoints, export_soup, main
from quad_il.learning.synthetic import write_synthetic_npz
from quad_il.learning.trainer import Trainer, load_policy_checkpoint


def _train(dataset: Path, out: Path, name: str, *extra: str) -> Path:
    return (
        Trainer(tiny_config(dataset, out, name, "optim.epochs=1", *extra)).fit().run_dir
        / "checkpoints"
        / "last.pt"
    )


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("soup")
    data = write_synthetic_npz(root / "d.npz", num_episodes=4, samples_per_episode=6, height=40, width=48)
    a = _train(data, root, "a", "run.seed=1")
    b = _train(data, root, "b", "run.seed=2")
    other = _train(data, root, "other", "run.seed=3", "model.depth_mlp=[16]")
    return {"a": a, "b": b, "other": other}


def test_the_average_is_the_mean_of_the_weights(checkpoints: dict[str, Path]) -> None:
    pa, _ = load_policy_checkpoint(checkpoints["a"])
    pb, _ = load_policy_checkpoint(checkpoints["b"])
    sa, sb = pa.state_dict(), pb.state_dict()
    soup, _ = average_checkpoints([checkpoints["a"], checkpoints["b"]])
    s = soup.state_dict()
    floats = [k for k in s if torch.is_floating_point(s[k])]
    assert floats and any(not torch.equal(sa[k], sb[k]) for k in floats)  # the two runs differ
    for k in floats:
        torch.testing.assert_close(s[k], (sa[k] + sb[k]) / 2, rtol=0, atol=1e-6)
    for k in set(s) - set(floats):  # integer buffers (BatchNorm batch counters) from the first
        assert torch.equal(s[k], sa[k])
    # Weights 3:1 give the weighted mean; weight 0 drops a checkpoint.
    w31, _ = average_checkpoints([checkpoints["a"], checkpoints["b"]], [3.0, 1.0])
    for k in floats:
        torch.testing.assert_close(w31.state_dict()[k], 0.75 * sa[k] + 0.25 * sb[k], rtol=0, atol=1e-6)
    only_a, _ = average_checkpoints([checkpoints["a"], checkpoints["b"]], [1.0, 0.0])
    for k in floats:
        torch.testing.assert_close(only_a.state_dict()[k], sa[k], rtol=0, atol=1e-6)


def test_the_exported_soup_is_a_policy_file_equal_to_the_averaged_network(
    checkpoints: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "sub" / "policy.ts"
    assert (
        main(
            ["--checkpoint", str(checkpoints["a"]), "--checkpoint", str(checkpoints["b"]), "--out", str(out)]
        )
        == 0
    )
    module, meta = load_exported(out)
    assert meta["run"]["soup_of"] == [str(checkpoints["a"]), str(checkpoints["b"])]
    assert meta["run"]["soup_weights"] == [1.0, 1.0]
    loaded = LoadedPolicy(out)  # the inference nodes' loader accepts it
    assert loaded.meta.num_ctrl_pts == meta["output"]["num_ctrl_pts"]
    soup, first = average_checkpoints([checkpoints["a"], checkpoints["b"]])
    inputs = seeded_check_inputs(ModelConfig.model_validate(first["config"]["model"]), seed=5)
    with torch.no_grad():
        torch.testing.assert_close(module(*inputs), soup(*inputs), rtol=0, atol=1e-4)
        pa, _ = load_policy_checkpoint(checkpoints["a"])
        assert not torch.allclose(module(*inputs), pa(*inputs), atol=1e-4)  # not just the first checkpoint


def test_bad_input_is_refused_with_the_reason(checkpoints: dict[str, Path], tmp_path: Path, capsys) -> None:
    a, b, other = checkpoints["a"], checkpoints["b"], checkpoints["other"]
    with pytest.raises(SoupError, match="at least 2 checkpoints, got 1"):
        average_checkpoints([a])
    with pytest.raises(SoupError, match=r"other.*last.pt: model settings differ .*model.depth_mlp"):
        average_checkpoints([a, other])
    with pytest.raises(SoupError, match="1 weights for 2 checkpoints"):
        average_checkpoints([a, b], [1.0])
    with pytest.raises(SoupError, match=r"weights \[-1.0, 2.0\]: must be >= 0"):
        average_checkpoints([a, b], [-1.0, 2.0])
    with pytest.raises(SoupError, match="no such checkpoint file .*missing.pt"):
        average_checkpoints([a, tmp_path / "missing.pt"])
    junk = tmp_path / "junk.pt"
    torch.save({"hello": 1}, junk)
    with pytest.raises(SoupError, match="junk.pt: not a quad_il training checkpoint"):
        average_checkpoints([a, junk])
    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint\n")
    with pytest.raises(SoupError, match="notes.pt: cannot read it as a training checkpoint"):
        average_checkpoints([a, text])
    out = tmp_path / "policy.ts"
    assert main(["--checkpoint", str(a), "--checkpoint", str(other), "--out", str(out)]) == 2
    assert "soup: error:" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SoupError):
        export_soup([a, other], out)
    assert not out.exists()

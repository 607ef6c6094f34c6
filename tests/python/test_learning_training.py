"""Training: typed config and its errors, seeded determinism, resume, NaN loss, run directory, scripts."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from quad_il.learning.checkpoint import read_training_checkpoint
from quad_il.learning.config import ConfigError, ModelConfig, TrainConfig, load_config
from quad_il.learning.export import load_exported
from quad_il.learning.model import Policy
from quad_il.learning.synthetic import write_synthetic_npz
from quad_il.learning.trainer import NonFiniteLossError, RunDirError, Trainer

ROOT = Path(__file__).resolve().parents[2]
LOSS_COLUMNS = [
    "epoch",
    "global_step",
    "lr",
    "train_loss",
    "val_loss",
    "val_mse_world_m2",
    "val_cosine_world",
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_npz(
        tmp_path_factory.mktemp("data") / "train.npz",
        num_episodes=6,
        samples_per_episode=6,
        height=40,
        width=48,
    )


def tiny_config(dataset: Path, out: Path, name: str, *extra: str) -> TrainConfig:
    return load_config(
        [ROOT / "config" / "train.yaml"],
        [
            f"data.paths=[{str(dataset)!r}]",
            f"run.out_dir={str(out)!r}",
            f"run.name={name}",
            "model.input_height=32",
            "model.input_width=32",
            "optim.batch_size=8",
            "optim.epochs=3",
            "log.progress=false",
            "log.tensorboard=false",
            "log.export_torchscript=false",
            "log.plots=false",
            "scheduler.custom.first_decay_steps=5",
            *extra,
        ],
    )


def loss_rows(run_dir: Path) -> list[list[str]]:
    with open(run_dir / "metrics.csv") as f:
        return [[r[c] for c in LOSS_COLUMNS] for r in csv.DictReader(f)]


# ----------------------------------------------------------------------------------------------------- config
def test_shipped_config_equals_the_defaults() -> None:
    assert load_config([ROOT / "config" / "train.yaml"]) == TrainConfig()
    for exp in sorted((ROOT / "config" / "experiments").glob("*.yaml")):
        load_config([ROOT / "config" / "train.yaml", exp])  # every experiment file validates


def test_config_typo_in_a_file_names_the_key(tmp_path: Path) -> None:
    path = tmp_path / "typo.yaml"
    path.write_text("model:\n  varaint: large\n")
    with pytest.raises(ConfigError, match=r"config key 'model.varaint': Extra inputs are not permitted"):
        load_config([path])


def test_config_override_errors_name_key_and_value() -> None:
    with pytest.raises(ConfigError, match=r"'optim.lr'.*greater than 0.*\(got -0.1\)"):
        load_config([], ["optim.lr=-0.1"])
    with pytest.raises(ConfigError, match=r"'scheduler.name'.*\(got 'linear'\)"):
        load_config([], ["scheduler.name=linear"])
    with pytest.raises(ConfigError, match=r"'data.split'.*'permuted' or 'hashed'.*\(got 'random'\)"):
        load_config([], ["data.split=random"])
    with pytest.raises(ConfigError, match=r"'optim.batchsize': Extra inputs"):
        load_config([], ["optim.batchsize=4"])
    with pytest.raises(ConfigError, match="must look like key.subkey=value"):
        load_config([], ["optim.lr"])
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(["/nonexistent/train.yaml"])


def test_overrides_are_typed_and_files_layer(tmp_path: Path) -> None:
    layer = tmp_path / "layer.yaml"
    layer.write_text(yaml.safe_dump({"optim": {"loss": "sse"}, "model": {"depth_mlp": [64, 32]}}))
    cfg = load_config([ROOT / "config" / "train.yaml", layer], ["optim.lr=3e-4", "model.variant=large"])
    assert cfg.optim.lr == 3e-4 and cfg.optim.loss == "sse" and cfg.model.variant == "large"
    assert cfg.model.depth_mlp == [64, 32] and cfg.model.state_mlp == [64, 32, 32]


# ------------------------------------------------------------------------------------------------ determinism
def test_two_runs_with_the_same_seed_give_identical_losses(dataset: Path, tmp_path: Path) -> None:
    a = Trainer(tiny_config(dataset, tmp_path, "a", "optim.epochs=2")).fit()
    b = Trainer(tiny_config(dataset, tmp_path, "b", "optim.epochs=2", "data.num_workers=2")).fit()
    rows_a, rows_b = loss_rows(a.run_dir), loss_rows(b.run_dir)
    assert len(rows_a) == 2 and rows_a == rows_b
    ckpt_a = read_training_checkpoint(a.run_dir / "checkpoints" / "last.pt")["model"]
    ckpt_b = read_training_checkpoint(b.run_dir / "checkpoints" / "last.pt")["model"]
    assert all(torch.equal(ckpt_a[k], ckpt_b[k]) for k in ckpt_a)
    c = Trainer(tiny_config(dataset, tmp_path, "c", "optim.epochs=1", "run.seed=1")).fit()
    assert loss_rows(c.run_dir)[0] != rows_a[0]


def test_multiple_hypotheses_train_deterministically_and_export(dataset: Path, tmp_path: Path) -> None:
    extra = ("optim.epochs=2", "model.hypotheses=3", "log.export_torchscript=true")
    a = Trainer(tiny_config(dataset, tmp_path, "mh_a", *extra)).fit()
    b = Trainer(tiny_config(dataset, tmp_path, "mh_b", *extra)).fit()
    assert loss_rows(a.run_dir) == loss_rows(b.run_dir)
    single = Trainer(tiny_config(dataset, tmp_path, "mh_1", "optim.epochs=2")).fit()
    assert loss_rows(single.run_dir) != loss_rows(a.run_dir)
    assert all(math.isfinite(r.val_mse_world_m2) for r in a.history)
    from quad_il.inference.policy import LoadedPolicy

    loaded = LoadedPolicy(a.policy_path)
    assert loaded.meta.hypotheses == 3 and loaded.meta.network_output_dim == 3 * (30 + 1)
    assert not loaded.meta.mean_first
    # The mean plan first: plan 0 trained on every sample, plans 1 and 2 winner-takes-all.
    extra_mean = ("optim.epochs=1", "model.hypotheses=3", "model.hypotheses_first=mean", extra[2])
    m = Trainer(tiny_config(dataset, tmp_path, "mh_mean", *extra_mean)).fit()
    assert loss_rows(m.run_dir)[0] != loss_rows(a.run_dir)[0]
    assert LoadedPolicy(m.policy_path).meta.mean_first


def test_resume_continues_the_same_curve(dataset: Path, tmp_path: Path) -> None:
    straight = Trainer(tiny_config(dataset, tmp_path, "straight", "optim.epochs=3")).fit()
    Trainer(tiny_config(dataset, tmp_path, "split", "optim.epochs=1", "log.tensorboard=true")).fit()
    resumed = Trainer(
        tiny_config(dataset, tmp_path, "split", "optim.epochs=3", "log.tensorboard=true"), resume=True
    ).fit()
    assert loss_rows(resumed.run_dir) == loss_rows(straight.run_dir)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(resumed.run_dir / "tensorboard")).Reload()
    steps = [e.step for e in events.Scalars("epoch/val_loss")]
    assert steps == [int(r[1]) for r in loss_rows(resumed.run_dir)]  # one point per epoch, at its last step
    assert [e.step for e in events.Scalars("step/lr")] == list(range(1, steps[-1] + 1))
    assert [r.epoch for r in resumed.history] == [1, 2, 3]
    info = json.loads((resumed.run_dir / "run_info.json").read_text())
    assert info["resumptions"][0]["from_epoch"] == 1


def test_init_weights_starts_from_a_checkpoint_and_rejects_another_model(
    dataset: Path, tmp_path: Path
) -> None:
    base = Trainer(tiny_config(dataset, tmp_path, "base", "optim.epochs=1")).fit()
    ckpt = base.run_dir / "checkpoints" / "last.pt"
    trained = read_training_checkpoint(ckpt)["model"]
    tuned = Trainer(
        tiny_config(dataset, tmp_path, "tuned", "optim.epochs=1", f"run.init_weights={str(ckpt)!r}")
    )
    start = tuned.policy.state_dict()
    assert all(torch.equal(start[k], trained[k]) for k in trained)  # starts where the checkpoint ended
    fresh = Trainer(tiny_config(dataset, tmp_path, "fresh", "optim.epochs=1")).policy.state_dict()
    assert not all(torch.equal(fresh[k], trained[k]) for k in trained)
    tuned.fit()
    assert loss_rows(tuned.run_dir)[0][3] != loss_rows(base.run_dir)[0][3]
    with pytest.raises(ValueError, match=r"run.init_weights: .*last.pt does not fit this model"):
        Trainer(
            tiny_config(dataset, tmp_path, "other", "model.depth_mlp=[16]", f"run.init_weights={str(ckpt)!r}")
        )
    with pytest.raises(
        ValueError, match=r"was trained with other model settings \(model.state_frame: world -> local"
    ):
        Trainer(
            tiny_config(
                dataset,
                tmp_path,
                "frames",
                "model.state_frame=local",
                "model.output_frame=local",
                f"run.init_weights={str(ckpt)!r}",
            )
        )
    with pytest.raises(FileNotFoundError, match="run.init_weights: no such checkpoint file"):
        Trainer(tiny_config(dataset, tmp_path, "missing", f"run.init_weights={str(tmp_path / 'no.pt')!r}"))


def test_resume_refuses_a_changed_configuration_and_reuse_needs_resume(dataset: Path, tmp_path: Path) -> None:
    Trainer(tiny_config(dataset, tmp_path, "r", "optim.epochs=1")).fit()
    with pytest.raises(ConfigError, match=r"optim.lr: 0.001 -> 0.01"):
        Trainer(tiny_config(dataset, tmp_path, "r", "optim.lr=0.01"), resume=True)
    with pytest.raises(RunDirError, match="already holds a run"):
        Trainer(tiny_config(dataset, tmp_path, "r"))
    with pytest.raises(RunDirError, match="nothing to resume"):
        Trainer(tiny_config(dataset, tmp_path, "never"), resume=True)


# -------------------------------------------------------------------------------------------------------- NaN
class NanForSentinelPolicy(Policy):
    """Outputs NaN for samples whose goal x is the sentinel value (a finite, valid record)."""

    SENTINEL = 12345.0

    def forward_prepared(self, depth_x, p_world_body, v_world, q_world_body, goal_world):  # type: ignore[override]
        y = super().forward_prepared(depth_x, p_world_body, v_world, q_world_body, goal_world)
        hit = (goal_world[:, 0] == self.SENTINEL).unsqueeze(1)
        return torch.where(hit, torch.full_like(y, float("nan")), y)


def test_nan_loss_stops_training_naming_the_batch(tmp_path: Path) -> None:
    from quad_il.learning.synthetic import make_synthetic_arrays

    arrays = make_synthetic_arrays(num_episodes=4, samples_per_episode=5)
    arrays["goal_world"][13, 0] = NanForSentinelPolicy.SENTINEL  # sample 13: world seed 1002, episode 2
    path = tmp_path / "sentinel.npz"
    np.savez(path, **arrays)
    from quad_il.learning.dataset import split_by_episode

    seed = next(
        s
        for s in range(50)
        if 13 in split_by_episode(arrays["world_seed"], arrays["episode_id"], 0.25, s).train_idx
    )
    cfg = tiny_config(path, tmp_path, "nan", "data.val_fraction=0.25", f"run.seed={seed}")

    def factory(model_cfg: ModelConfig, k: int, horizon: float) -> Policy:
        return NanForSentinelPolicy(model_cfg, k, horizon)

    trainer = Trainer(cfg, policy_factory=factory)
    assert 13 in trainer.split.train_idx  # the sentinel sample is trained on with this seed
    with pytest.raises(
        NonFiniteLossError,
        match=r"training loss at epoch \d+, step \d+: batch .*\b13\b.*sample 13 \(world_seed 1002, "
        r"episode 2\)",
    ):
        trainer.fit()


# ---------------------------------------------------------------------------------------------------- run dir
def test_run_directory_holds_config_seed_manifest_commit_curves_and_policy(
    dataset: Path, tmp_path: Path
) -> None:
    cfg = tiny_config(
        dataset,
        tmp_path,
        "full",
        "optim.epochs=2",
        "log.tensorboard=true",
        "log.export_torchscript=true",
        "log.plots=true",
        "model.output_frame=local",
    )
    result = Trainer(cfg).fit()
    d = result.run_dir
    assert load_config([d / "config.yaml"]) == cfg
    info = json.loads((d / "run_info.json").read_text())
    assert info["seed"] == 0 and len(info["software"]["commit"]) in (40, len("unknown"))
    manifest = json.loads((d / "dataset_manifest.json").read_text())
    assert manifest["num_samples"] == 36 and len(manifest["sources"][0]["sha256"]) == 64
    split = manifest["split"]
    assert not {tuple(e) for e in split["train_episodes"]} & {tuple(e) for e in split["val_episodes"]}
    assert split["num_train_samples"] + split["num_val_samples"] == 36
    assert list((d / "tensorboard").glob("events.out.tfevents.*"))
    assert (d / "loss_curves.png").stat().st_size > 10_000
    assert (d / "checkpoints" / "best.pt").is_file()
    summary = json.loads((d / "summary.json").read_text())
    assert summary["export_max_abs_diff"] <= 1e-4
    module, meta = load_exported(d / "policy.ts")
    assert meta["output"]["network_frame"] == "local"
    assert meta["dataset"]["train_world_seeds"] == split["train_world_seeds"]
    assert meta["run"]["best_epoch"] == result.best_epoch
    # The exported file and the eager checkpoint it came from evaluate identically.
    from quad_il.learning.evaluation import evaluate

    via_file = evaluate(d, [dataset], tmp_path / "eval_ts", allow_seen_worlds=True)["metrics"]
    via_ckpt = evaluate(d / "checkpoints" / "best.pt", [dataset], tmp_path / "eval_pt")["metrics"]
    for key, stats in via_file.items():
        assert stats["mean"] == pytest.approx(via_ckpt[key]["mean"], rel=1e-5, abs=1e-7), key


def test_training_reduces_the_loss_on_a_learnable_task(tmp_path: Path) -> None:
    path = write_synthetic_npz(
        tmp_path / "learn.npz", num_episodes=10, samples_per_episode=8, height=32, width=32
    )
    cfg = tiny_config(
        path,
        tmp_path,
        "learn",
        "optim.epochs=6",
        "model.output_frame=local",
        "model.state_frame=local",
        "scheduler.name=none",
        "optim.batch_size=16",
    )
    history = Trainer(cfg).fit().history
    assert history[-1].train_loss < 0.5 * history[0].train_loss


# ---------------------------------------------------------------------------------------------------- scripts
def _import_script(name: str):
    sys.path.insert(0, str(ROOT / "training_only"))
    try:
        return __import__(name)
    finally:
        sys.path.pop(0)


def test_train_script_reports_config_and_dataset_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = _import_script("train_on_cpp_datasets")
    assert script.main(["--set", "optim.lossfn=mse", "--data", str(tmp_path)]) == 2
    assert "optim.lossfn" in capsys.readouterr().err
    assert script.main(["--data", str(tmp_path / "missing.npz"), "--out", str(tmp_path)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_train_script_trains_and_experiment_script_compares(dataset: Path, tmp_path: Path) -> None:
    common = [
        "--set",
        "model.input_height=32",
        "--set",
        "model.input_width=32",
        "--set",
        "optim.batch_size=8",
        "--set",
        "log.progress=false",
        "--set",
        "log.tensorboard=false",
        "--set",
        "data.hash_files=false",
    ]
    script = _import_script("train_on_cpp_datasets")
    rc = script.main(
        [
            "--config",
            str(ROOT / "config" / "train.yaml"),
            "--data",
            str(dataset),
            "--out",
            str(tmp_path),
            "--name",
            "cli",
            "--epochs",
            "1",
            *common,
        ]
    )
    assert rc == 0 and (tmp_path / "cli" / "policy.ts").is_file()
    # Resuming needs only the run's name: its own config.yaml (input size, data paths...) is reused.
    rc = script.main(
        ["--out", str(tmp_path), "--name", "cli", "--resume", "--epochs", "2", "--set", "log.progress=false"]
    )
    assert rc == 0 and len(loss_rows(tmp_path / "cli")) == 2
    experiment = _import_script("run_experiment")
    rc = experiment.main(
        [
            "loss",
            "--data",
            str(dataset),
            "--out",
            str(tmp_path / "exp"),
            "--epochs",
            "1",
            *common,
            "--set",
            "log.export_torchscript=false",
        ]
    )
    assert rc == 0
    exp = tmp_path / "exp" / "loss"
    assert (exp / "comparison.png").is_file()
    table = (exp / "comparison.md").read_text()
    assert "| loss_mse | 1 |" in table and "| loss_sse | 1 |" in table
    mse = loss_rows(exp / "loss_mse")[0]
    sse = loss_rows(exp / "loss_sse")[0]
    # The experiment's overrides reached the runs: per sample SSE = 3K * MSE = 30 * MSE, so the SSE run's loss
    # column is on a 30x larger scale (the validation MSE in the world frame is the common scale of both).
    assert float(sse[3]) > 5 * float(mse[3])


def test_end_to_end_from_real_collector_shards_to_evaluation(tmp_path: Path) -> None:
    """Shards written by cpp_data_collector's writer -> training reads them directly -> evaluation on shards
    of other worlds, through the exported policy file."""
    from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
    from quad_il.learning.evaluation import evaluate

    try:
        find_collector_tool("write_synthetic_dataset")
    except FileNotFoundError as e:
        pytest.skip(f"cpp_data_collector not built: {e}")
    train = write_synthetic_dataset(
        tmp_path / "train", seed=3, records=40, width=64, height=48, records_per_episode=10
    )
    heldout = write_synthetic_dataset(
        tmp_path / "heldout", seed=4, records=20, width=64, height=48, records_per_episode=10
    )
    cfg = tiny_config(
        train, tmp_path, "shards", "optim.epochs=1", "log.export_torchscript=true", "data.val_fraction=0.25"
    )
    result = Trainer(cfg).fit()
    manifest = json.loads((result.run_dir / "dataset_manifest.json").read_text())
    assert manifest["sources"][0]["kind"] == "shards"
    assert manifest["sources"][0]["collector_manifest"]["path"].endswith("manifest.yaml")
    summary = evaluate(result.run_dir, [heldout], tmp_path / "eval")
    assert summary["num_samples"] == 20 and summary["held_out"]["overlap_with_training"] == []

"""EIL in the trainer (optim.loss = eil): the per-row objective, the npz `il_partition` array from the
converter to the trainer, and its errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_imitation_dataset import make_records

from quad_il.data.partitions import IL_PARTITION_KEY, PARTITION_CODES, Partition
from quad_il.imitation.convert import convert, parse_partitions, records_to_npz_arrays
from quad_il.imitation.dataset import write_dataset
from quad_il.learning.config import ConfigError, load_config
from quad_il.learning.dataset import DatasetError, concatenate, prepare_arrays, read_npz
from quad_il.learning.eil import eil_loss
from quad_il.learning.losses import eil_per_sample
from quad_il.learning.preprocessing import DepthPreprocessor
from quad_il.learning.synthetic import make_synthetic_arrays
from quad_il.learning.trainer import Trainer

ROOT = Path(__file__).resolve().parents[2]
CODES = PARTITION_CODES


def test_per_row_objective_matches_eil_loss_and_hand_values() -> None:
    gen = torch.Generator().manual_seed(0)
    pred = torch.randn(8, 30, generator=gen)
    label = pred + 0.3 * torch.randn(8, 30, generator=gen)
    part = torch.tensor(
        [CODES[p] for p in [Partition.DEMO, Partition.INTERVENTION, Partition.GOOD, Partition.BAD]] * 2
    )
    per = eil_per_sample(pred, label, part, threshold_b_m=0.5, intervention_weight=2.0)
    total = eil_loss(pred, label, part, threshold_b_m=0.5, intervention_weight=2.0).total
    torch.testing.assert_close(per.mean(), total)
    # Hand values: one control point 1 m off, the other 9 exact: D = 1/10 m^2 (B = 0.25 m^2).
    p = torch.zeros(4, 30)
    t = torch.zeros(4, 30)
    t[:, 0] = 1.0
    rows = torch.tensor(
        [CODES[Partition.DEMO], CODES[Partition.GOOD], CODES[Partition.BAD], CODES[Partition.BAD]]
    )
    t[3, 0] = 0.0  # a bad plan identical to the prediction: the full penalty B
    got = eil_per_sample(p, t, rows, threshold_b_m=0.5, intervention_weight=1.0)
    torch.testing.assert_close(got, torch.tensor([0.1, 0.0, 0.15, 0.25]))
    with pytest.raises(ValueError, match="partition must have shape"):
        eil_per_sample(p, t, rows[:2], 0.5, 1.0)


def test_converter_writes_il_partition_and_the_reader_keeps_it(tmp_path: Path) -> None:
    write_dataset(tmp_path / "r0", make_records(8))  # demo, intervention, good, bad, ...
    out, n, _ = convert(
        [tmp_path / "r0"], tmp_path / "d.npz", partitions=parse_partitions("demo,intervention,good,bad")
    )
    arrays = read_npz(out)
    assert arrays[IL_PARTITION_KEY].tolist() == [0, 1, 2, 3, 0, 1, 2, 3] and n == 8
    data, _ = prepare_arrays(arrays, DepthPreprocessor(32, 32, 10.0), str(out))
    assert data.partition is not None and data.partition.tolist() == [0, 1, 2, 3, 0, 1, 2, 3]
    # With a source without the array (the C++ collector's), its rows are DEMO.
    other, _ = prepare_arrays(
        make_synthetic_arrays(num_episodes=2, samples_per_episode=2, height=24, width=24, num_ctrl_pts=10),
        DepthPreprocessor(32, 32, 10.0),
        "cpp",
    )
    both = concatenate([other, data])
    assert both.partition is not None and both.partition.tolist() == [0] * 4 + [0, 1, 2, 3, 0, 1, 2, 3]
    assert concatenate([other, other]).partition is None


def test_bad_il_partition_values_are_named() -> None:
    arrays = make_synthetic_arrays(num_episodes=2, samples_per_episode=2, height=24, width=24)
    arrays[IL_PARTITION_KEY] = np.array([0, 1, 7, 0], dtype=np.int32)
    with pytest.raises(
        DatasetError, match=r"src: il_partition of record 2 is 7, not a partition code \[0, 1, 2, 3\]"
    ):
        prepare_arrays(arrays, DepthPreprocessor(32, 32, 10.0), "src")
    arrays[IL_PARTITION_KEY] = np.zeros(3, dtype=np.int32)
    with pytest.raises(DatasetError, match=r"il_partition must be \(4,\) integers"):
        prepare_arrays(arrays, DepthPreprocessor(32, 32, 10.0), "src")


def test_extra_npz_arrays_never_replace_contract_keys(tmp_path: Path) -> None:
    fixed = records_to_npz_arrays(make_records(2))
    with pytest.raises(ValueError, match="extra array 'episode_id' would replace a key"):
        fixed.save(tmp_path / "x.npz", extra={"episode_id": np.zeros(2)})
    with pytest.raises(ValueError, match="extra array 'il_partition' has 3 rows, the records are 2"):
        fixed.save(tmp_path / "x.npz", extra={IL_PARTITION_KEY: np.zeros(3, dtype=np.int32)})


def _eil_dataset(tmp_path: Path) -> Path:
    arrays = make_synthetic_arrays(num_episodes=6, samples_per_episode=6, height=40, width=48)
    arrays[IL_PARTITION_KEY] = (np.arange(36) % 4).astype(np.int32)
    path = tmp_path / "eil.npz"
    np.savez(path, **arrays)
    return path


def _config(data: Path, out: Path, name: str, *extra: str):  # noqa: ANN202
    return load_config(
        [ROOT / "config" / "train.yaml"],
        [
            f"data.paths=[{str(data)!r}]",
            f"run.out_dir={str(out)!r}",
            f"run.name={name}",
            "model.input_height=32",
            "model.input_width=32",
            "optim.batch_size=8",
            "optim.epochs=2",
            "log.progress=false",
            "log.tensorboard=false",
            "log.export_torchscript=false",
            "log.plots=false",
            *extra,
        ],
    )


def test_trainer_optimises_the_eil_objective_on_partitioned_rows(tmp_path: Path) -> None:
    data = _eil_dataset(tmp_path)
    eil = Trainer(_config(data, tmp_path, "eil", "optim.loss=eil", "optim.eil.threshold_b_m=0.3"))
    assert eil.partition.tolist() == (np.arange(36) % 4).tolist()
    # The trainer's loss on a batch is eil_per_sample with the rows' own partitions.
    batch = next(iter(eil.train_loader.epoch(1)))
    y = eil.policy.forward_prepared(
        batch.depth_x, batch.p_world_body, batch.v_world, batch.q_world_body, batch.goal_world
    )
    loss, per = eil._batch_loss(y, batch)
    part = torch.from_numpy((batch.indices % 4).astype(np.int32))
    torch.testing.assert_close(per, eil_per_sample(y, batch.target, part, 0.3, 1.0))
    eil.fit()
    mse = Trainer(_config(data, tmp_path, "mse")).fit()
    assert eil.history[-1].train_loss != mse.history[-1].train_loss


def test_eil_needs_the_bspline_output() -> None:
    with pytest.raises(ConfigError, match="optim.loss: eil measures distances between control points"):
        load_config([], ["optim.loss=eil", "model.output=polynomial"])

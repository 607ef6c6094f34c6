"""Round datasets -> the trainer's npz contract (quad_il.imitation.convert)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from test_imitation_dataset import make_records

from quad_il.data.bspline import evaluate, uniform_knots
from quad_il.data.format import DatasetError
from quad_il.imitation import Partition, Record, SplineAction
from quad_il.imitation.convert import convert, parse_partitions, records_to_npz_arrays
from quad_il.imitation.dataset import write_dataset
from quad_il.learning.dataset import validate_arrays
from quad_il.learning.preprocessing import world_to_local_points, yaw_from_quaternion


def test_a_uniform_cubic_label_on_the_target_grid_is_reproduced_exactly() -> None:
    # A label that already is a uniform cubic with K = 10 over 2 s starting at the frame: the fit returns it.
    rec = make_records(1)[0]
    ctrl = np.random.default_rng(3).normal(size=(10, 3))
    label = SplineAction.uniform(ctrl, 2.0 / 7, start_time_s=rec.obs.stamp_s)
    rec = dataclasses.replace(rec, label=label)
    a = records_to_npz_arrays([rec])
    np.testing.assert_allclose(a.bspline_ctrl_world[0], ctrl, atol=1e-5)
    assert a.fit_rms_m[0] < 1e-6
    # The npz spline evaluates like the label over the horizon.
    u = np.linspace(0.0, 2.0, 9)
    y = evaluate(uniform_knots(10, 3, 2.0 / 7), a.bspline_ctrl_world[0].astype(np.float64), 3, u)
    np.testing.assert_allclose(y, label.positions(rec.obs.stamp_s + u), atol=1e-5)


def test_converted_arrays_pass_the_trainers_validation_and_frames(tmp_path: Path) -> None:
    recs = make_records(8)
    recs = [
        dataclasses.replace(r, obs=dataclasses.replace(r.obs, odom_stamp_s=r.obs.stamp_s - 0.002))
        for r in recs
    ]
    write_dataset(tmp_path / "r0", recs[:4])
    write_dataset(tmp_path / "r1", [dataclasses.replace(r, round_index=3) for r in recs[4:]])
    out, n, skipped = convert(
        [tmp_path / "r0", tmp_path / "r1"],
        tmp_path / "d.npz",
        partitions=parse_partitions("demo,intervention,good,bad"),
    )
    assert n == 8 and skipped == {}
    with np.load(out) as data:
        arrays = {k: data[k] for k in data.files}
    assert validate_arrays(arrays, "d.npz")[:2] == (8, 10)
    assert arrays["depth_m"].dtype == np.float16
    np.testing.assert_array_equal(arrays["world_seed"], [2, 2, 2, 2, 3, 3, 3, 3])  # (round, episode) keys
    np.testing.assert_allclose(arrays["depth_stamp_s"] - arrays["odom_stamp_s"], 0.002, atol=1e-9)
    import torch

    local = world_to_local_points(
        torch.from_numpy(arrays["bspline_ctrl_world"]).double(),
        torch.from_numpy(arrays["p_world_body"]).double(),
        yaw_from_quaternion(torch.from_numpy(arrays["q_world_body"]).double()),
    )
    np.testing.assert_allclose(local.numpy(), arrays["bspline_ctrl_local"], atol=1e-4)


def test_only_the_wanted_partitions_are_kept(tmp_path: Path) -> None:
    write_dataset(tmp_path, make_records(8))  # partitions cycle demo, intervention, good, bad
    _, n, skipped = convert([tmp_path], tmp_path / "x.npz")
    assert n == 4 and skipped == {"good": 2, "bad": 2}
    with pytest.raises(DatasetError, match="no records to convert"):
        convert([tmp_path], tmp_path / "y.npz", partitions=(Partition.GOOD,) * 0)
    with pytest.raises(DatasetError, match="--partitions 'demo,best'"):
        parse_partitions("demo,best")
    with pytest.raises(DatasetError, match="records without depth"):
        records_to_npz_arrays(make_records(2, depth=False))


def test_stride_keeps_every_nth_wanted_record_of_each_episode(tmp_path: Path) -> None:
    recs = make_records(8)  # partitions cycle demo, intervention, good, bad: 4 wanted per episode
    write_dataset(tmp_path, [episode(r, 1) for r in recs] + [episode(r, 2) for r in recs])
    _, n, skipped = convert([tmp_path], tmp_path / "s.npz", stride=3)
    # Wanted records per episode: indices 0, 1, 4, 5 -> the 1st and 4th are kept (0 and 5).
    assert n == 4 and skipped == {"good": 4, "bad": 4, "stride": 4}
    with np.load(tmp_path / "s.npz") as data:
        seqs = data["record_seq"].tolist()
    assert seqs == [0, 5, 8, 13]  # the dataset's seqs of the kept records
    with pytest.raises(DatasetError, match="--stride must be >= 1, got 0"):
        convert([tmp_path], tmp_path / "z.npz", stride=0)


def episode(r: Record, episode_id: int) -> Record:
    return dataclasses.replace(r, obs=dataclasses.replace(r.obs, episode_id=episode_id))


def _fake_train(argv: list[str]) -> int:
    """Stands in for quad_il.learning.train.main (what the round's training is called with, in-process)."""
    data = Path(argv[argv.index("--data") + 1])
    out = Path(argv[argv.index("--out") + 1]) / argv[argv.index("--name") + 1]
    # What the manager's training step must guarantee: the converted copy exists while training runs.
    assert data.is_file(), data
    out.mkdir(parents=True, exist_ok=True)
    (out / "seen.txt").write_text(str(data.stat().st_size))
    if "--fail" in argv:
        return 3
    (out / "policy.ts").write_bytes(b"policy")
    return 0


def _train_round(tmp_path: Path, *extra: str) -> tuple[int, Path]:
    import quad_il.learning.train
    from quad_il.imitation.convert import main

    write_dataset(tmp_path / "r0", make_records(4))
    ckpt = tmp_path / "ckpt"
    mp = pytest.MonkeyPatch()
    mp.setattr(quad_il.learning.train, "main", _fake_train)
    try:
        code = main(["train", "--data-dirs", str(tmp_path / "r0"), "--checkpoint-dir", str(ckpt), *extra])
    finally:
        mp.undo()
    return code, ckpt


def test_train_round_removes_the_converted_copy_after_a_successful_training(tmp_path: Path) -> None:
    code, ckpt = _train_round(tmp_path)
    assert code == 0
    assert int((ckpt / "train" / "seen.txt").read_text()) > 0  # the trainer read a real npz
    assert (ckpt / "policy.ts").read_bytes() == b"policy"
    assert not (ckpt / "dataset.npz").exists()
    assert (tmp_path / "r0").is_dir() and any(
        (tmp_path / "r0").iterdir()
    )  # the round data it came from stays


def test_train_round_keeps_the_converted_copy_when_asked_or_when_training_fails(tmp_path: Path) -> None:
    code, ckpt = _train_round(tmp_path / "keep", "--keep-dataset")
    assert code == 0 and (ckpt / "dataset.npz").is_file()
    code, ckpt = _train_round(tmp_path / "fail", "--set=--fail")
    assert code == 3
    assert (ckpt / "dataset.npz").is_file() and not (ckpt / "policy.ts").exists()


def test_train_round_trains_in_this_process_with_the_real_trainer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The round's training is quad_il.learning.train called as a function: no script, no child process."""
    import subprocess

    from quad_il.imitation.convert import main

    real_popen = subprocess.Popen

    def no_training_child(cmd, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        text = " ".join(map(str, cmd)) if isinstance(cmd, list | tuple) else str(cmd)
        assert "train" not in text, f"train_round started a training process: {text}"
        return real_popen(cmd, *args, **kwargs)  # e.g. the run manifest's `git rev-parse`

    monkeypatch.setattr(subprocess, "Popen", no_training_child)
    root = Path(__file__).resolve().parents[2]
    rng = np.random.default_rng(3)  # depth at least the network's 32x32 input (the loader refuses smaller)
    recs = [
        dataclasses.replace(
            r,
            obs=dataclasses.replace(
                r.obs, episode_id=ep, depth_m=rng.uniform(0, 10, size=(32, 32)).astype(np.float32)
            ),
        )
        for ep in range(4)
        for r in make_records(8)
    ]
    write_dataset(tmp_path / "r0", recs)
    ckpt = tmp_path / "ckpt"
    overrides = [
        "optim.epochs=1",
        "optim.batch_size=4",
        "model.input_height=32",
        "model.input_width=32",
        "data.num_workers=0",
        "log.progress=false",
        "log.tensorboard=false",
        "log.plots=false",
    ]
    argv = ["train", "--data-dirs", str(tmp_path / "r0"), "--checkpoint-dir", str(ckpt)]
    argv += ["--config", str(root / "config" / "train.yaml"), *[f"--set={kv}" for kv in overrides]]
    assert main(argv) == 0
    assert (ckpt / "policy.ts").read_bytes() == (ckpt / "train" / "policy.ts").read_bytes()
    assert "optim:\n" in (ckpt / "train" / "config.yaml").read_text()
    assert not (ckpt / "dataset.npz").exists()

"""collect.launch's argument handling: the episode manager's parameters and the launch-time preparation."""

from pathlib import Path

import pytest
import yaml

from quad_il.collection.episodes import manager_config, parse_seeds
from quad_il.collection.prepare import (
    PrepareError,
    main,
    make_sim_config,
    prepare_output_dir,
    resolve_output_dir,
)

ROOT = Path(__file__).resolve().parents[2]
COLLECT_YAML = ROOT / "config" / "collect.yaml"
SIM_YAML = ROOT / "config" / "sim.yaml"


def test_repository_config_and_overrides():
    cfg = manager_config(COLLECT_YAML, {})
    assert cfg.episodes >= 1 and cfg.seeds
    cfg = manager_config(
        COLLECT_YAML,
        {
            "output_dir": "/tmp/x",
            "seeds": "5, 6, 10-12",
            "episodes": 4,
            "max_samples": 10,
            "episode_timeout_s": 12.5,
        },
    )
    assert (cfg.output_dir, cfg.seeds, cfg.episodes, cfg.max_samples, cfg.episode_timeout_s) == (
        "/tmp/x",
        [5, 6, 10, 11, 12],
        4,
        10,
        12.5,
    )
    # 0 / "" / negative max_samples keep the config's values.
    base = manager_config(COLLECT_YAML, {})
    same = manager_config(
        COLLECT_YAML, {"seeds": "", "episodes": 0, "max_samples": -1, "episode_timeout_s": 0}
    )
    assert same == base


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"seeds": "1,x"}, "seeds 'x': not a list of integers"),
        ({"seeds": "-3"}, "seeds '-3': '-3' is not a range like 100-199"),
        ({"seeds": "9-5"}, "seeds '9-5': bad seed range '9-5' is empty"),
        ({"episodes": -2}, "episodes -2: must be >= 1"),
        ({"episodes": "many"}, "episodes 'many': not a number"),
        ({"episodes": 2.5}, "episodes '2.5': not an integer"),
        ({"max_samples": True}, "max_samples 'True': not a number"),
        ({"episode_timeout_s": -1}, "episode_timeout_s -1.0: must be > 0"),
        ({"speed": 3}, "unknown episode manager parameter(s): speed"),
    ],
)
def test_bad_manager_arguments_name_the_argument(params, message):
    with pytest.raises(ValueError) as e:
        manager_config(COLLECT_YAML, params)
    assert message in str(e.value)


def test_bad_config_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="collection config not found"):
        manager_config(tmp_path / "none.yaml", {})
    p = tmp_path / "c.yaml"
    p.write_text("episodes: 2\nrestart_tracker: maybe\n")
    with pytest.raises(ValueError, match="restart_tracker"):
        manager_config(p, {})
    p.write_text("episodes: 2\nlaps: 3\n")
    with pytest.raises(ValueError, match="laps"):
        manager_config(p, {})


def test_parse_seeds():
    assert parse_seeds("1,2 3") == [1, 2, 3]
    assert parse_seeds("") == []


def test_output_dir_resolution_and_refusal(tmp_path):
    assert resolve_output_dir("data/x", root=tmp_path) == (tmp_path / "data" / "x").resolve()
    assert resolve_output_dir(str(tmp_path / "abs")) == (tmp_path / "abs").resolve()
    d = prepare_output_dir(str(tmp_path / "new" / "ds"))
    assert d.is_dir()
    assert prepare_output_dir(str(d)) == d  # empty (or only a sim config): fine
    for name in ("manifest.yaml", "shard_000000.qdr.partial", "episodes.csv"):
        existing = tmp_path / f"with_{name}"
        existing.mkdir()
        (existing / name).write_text("")
        with pytest.raises(PrepareError, match=f"already holds a dataset \\({name}\\)"):
            prepare_output_dir(str(existing))
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(PrepareError, match="exists and is not a directory"):
        prepare_output_dir(str(f))
    with pytest.raises(PrepareError, match="output_dir is empty"):
        prepare_output_dir("  ")


@pytest.mark.parametrize("mode", ["lockstep", "realtime", "factor"])
def test_sim_config_per_time_mode(tmp_path, mode):
    out = make_sim_config(tmp_path, SIM_YAML, mode, factor=2.5, consumers=["fast_planner", "episode_manager"])
    cfg = yaml.safe_load(out.read_text())
    base = yaml.safe_load(SIM_YAML.read_text())
    assert cfg["time"]["mode"] == {"lockstep": "lockstep", "realtime": "real_time", "factor": "factor"}[mode]
    assert cfg["time"]["real_time_factor"] == (2.5 if mode == "factor" else 1.0)
    lockstep = mode == "lockstep"
    assert cfg["lockstep"]["wait_for_command"] is lockstep
    assert cfg["lockstep"]["depth_consumers"] == (["fast_planner", "episode_manager"] if lockstep else [])
    assert Path(cfg["vehicle_file"]).is_absolute() and Path(cfg["vehicle_file"]).is_file()
    # Everything else is the base config's.
    for key in ("physics", "camera", "world", "episode"):
        assert cfg[key] == base[key]


def test_sim_config_errors(tmp_path):
    with pytest.raises(PrepareError, match="time_mode 'fast' is not one of lockstep, realtime, factor"):
        make_sim_config(tmp_path, SIM_YAML, "fast")
    with pytest.raises(PrepareError, match="time_factor 0.0 must be > 0"):
        make_sim_config(tmp_path, SIM_YAML, "factor", factor=0.0)
    with pytest.raises(PrepareError, match="not found"):
        make_sim_config(tmp_path, tmp_path / "none.yaml", "lockstep")
    other = tmp_path / "other.yaml"
    other.write_text("a: 1\n")
    with pytest.raises(PrepareError, match="is not a quad_sim config"):
        make_sim_config(tmp_path, other, "lockstep")


def test_cli_prints_path_without_newline_and_reports_errors(tmp_path, capsys):
    assert main(["output-dir", str(tmp_path / "d")]) == 0
    assert capsys.readouterr().out == str((tmp_path / "d").resolve())
    (tmp_path / "d" / "manifest.yaml").write_text("")
    assert main(["sim-config", str(tmp_path / "d"), "--base", str(SIM_YAML), "--time-mode", "lockstep"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("collect.launch: error: output_dir") and "already holds a dataset" in err

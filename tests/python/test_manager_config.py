"""Manager configuration: the shipped file is valid; every error names the key (and the value)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from quad_il.imitation.config import DAggerConfig
from quad_il.manager.config import ConfigError, config_digest, config_from_tree, load_config

ROOT = Path(__file__).resolve().parents[2]

MINIMAL: dict[str, Any] = {
    "run": {"run_dir": "/tmp/run"},
    "simulator": {"command": ["sim"]},
    "expert": {"command": ["expert"]},
    "collector": {"command": ["collect", "{data_dir}"]},
    "algorithm": {"name": "hg_dagger"},
    "rounds": {"count": 2},
    "training": {"command": ["train", "{data_dirs}", "{checkpoint_dir}"]},
}


def with_change(path: str, value: Any) -> dict[str, Any]:
    """MINIMAL with one dotted key set (value None deletes it)."""
    tree = copy.deepcopy(MINIMAL)
    *parents, last = path.split(".")
    node = tree
    for p in parents:
        node = node.setdefault(p, {})
    if value is None:
        del node[last]
    else:
        node[last] = value
    return tree


def test_the_shipped_config_is_valid() -> None:
    cfg, text = load_config(ROOT / "config" / "il_manager.yaml")
    assert isinstance(cfg.algorithm, DAggerConfig)
    assert cfg.rounds.count == 5 and cfg.ros.port == "auto"
    assert "imitation_learning_manager.py" in text


def test_minimal_config_gets_documented_defaults() -> None:
    cfg = config_from_tree(MINIMAL)
    assert cfg.signals.sigint_timeout_s == 15.0 and cfg.signals.sigterm_timeout_s == 5.0
    assert cfg.ros.enabled and cfg.ros.roscore_command == ["roscore", "-p", "{ros_port}"]
    assert not cfg.tracker.enabled and not cfg.learner.enabled and not cfg.eval.enabled
    assert cfg.training.policy_file == "policy.pt"


@pytest.mark.parametrize(
    ("tree", "expected"),
    [
        (
            {**MINIMAL, "simulatr": {"command": ["x"]}},
            "config key 'simulatr': Extra inputs are not permitted",
        ),
        (
            with_change("collector.timeout", 5),
            "config key 'collector.timeout': Extra inputs are not permitted",
        ),
        (
            with_change("rounds.count", 0),
            "config key 'rounds.count': Input should be greater than or equal to 1 (got 0)",
        ),
        (with_change("training.command", None), "config key 'training.command': Field required"),
        (with_change("run", None), "config key 'run': Field required"),
        (
            with_change("signals.sigint_timeout_s", -1),
            "config key 'signals.sigint_timeout_s': Input should be greater than 0",
        ),
        (
            with_change("ros.port", 80),
            "config key 'ros.port': Value error, must be 'auto' or in [1024, 65535] (got 80)",
        ),
        (
            with_change("simulator.command", None),
            "config key 'simulator': Value error, 'command' is required when 'enabled' is true",
        ),
        (
            with_change("collector.command", "collect.sh"),
            "config key 'collector.command': Input should be a valid list",
        ),
        (
            with_change("collector.command", ["a", 3]),
            "config key 'collector.command[1]': Input should be a valid string",
        ),
        (
            with_change("algorithm", {"name": "hg_dagger", "gate": {"on_threshold_m": -1}}),
            "config key 'algorithm.hg_dagger.gate.on_threshold_m': Input should be greater than 0 (got -1)",
        ),
        (
            with_change("algorithm", {"name": "dagger", "beta": {"decay": 2}}),
            "config key 'algorithm.dagger.beta.decay': Input should be less than 1 (got 2)",
        ),
        (
            with_change("algorithm", {"name": "dagga"}),
            "config key 'algorithm': Input tag 'dagga' found using 'name'",
        ),
    ],
)
def test_validation_errors_name_the_key(tree: dict[str, Any], expected: str) -> None:
    with pytest.raises(ConfigError) as e:
        config_from_tree(tree)
    assert expected in str(e.value)


def test_unknown_placeholders_name_the_key_and_list_the_known_ones() -> None:
    with pytest.raises(ConfigError) as e:
        config_from_tree(with_change("training.command", ["train", "--out", "{chekpoint_dir}"]))
    msg = str(e.value)
    assert "config key 'training.command[2]': unknown placeholder {chekpoint_dir}" in msg
    assert "checkpoint_dir" in msg and "data_dirs" in msg
    with pytest.raises(
        ConfigError, match=r"config key 'expert.env.ROS_NAMESPACE': unknown placeholder \{ns\}"
    ):
        config_from_tree(with_change("expert.env", {"ROS_NAMESPACE": "{ns}"}))
    with pytest.raises(ConfigError, match=r"config key 'collector.command\[1\]': bad template"):
        config_from_tree(with_change("collector.command", ["c", "{data_dir"]))


def test_disabled_services_need_no_command() -> None:
    cfg = config_from_tree(with_change("simulator", {"enabled": False}))
    assert not cfg.simulator.enabled and cfg.simulator.command is None


def test_bad_files_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    (tmp_path / "bad.yaml").write_text("run: [unclosed\n")
    with pytest.raises(ConfigError, match="is not valid YAML"):
        load_config(tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="must hold a mapping at the top level, got list"):
        load_config(tmp_path / "list.yaml")


def test_digest_ignores_formatting_but_not_values(tmp_path: Path) -> None:
    a = tmp_path / "a.yaml"
    b = tmp_path / "b.yaml"
    a.write_text(yaml.safe_dump(MINIMAL, sort_keys=True))
    b.write_text("# a comment\n" + yaml.safe_dump(MINIMAL, sort_keys=False))
    assert config_digest(load_config(a)[0]) == config_digest(load_config(b)[0])
    assert config_digest(config_from_tree(with_change("rounds.count", 3))) != config_digest(load_config(a)[0])

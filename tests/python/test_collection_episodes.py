"""Episode planning of a collection run: deterministic, inside the area, stop conditions, crash-safe log."""

import numpy as np
import pytest

from quad_il.collection.episodes import (
    CollectConfig,
    EpisodeLog,
    EpisodeOutcome,
    StartGoalConfig,
    StopCondition,
    load_collect_config,
    plan_episode,
)


def test_same_config_gives_same_episodes():
    cfg = CollectConfig(seeds=[3, 7], episodes=4)
    assert [plan_episode(cfg, i) for i in range(4)] == [plan_episode(cfg, i) for i in range(4)]
    assert [plan_episode(cfg, i).seed for i in range(4)] == [3, 7, 3, 7]
    # Cycled seeds give different start/goal pairs per episode index.
    assert plan_episode(cfg, 0).start_world != plan_episode(cfg, 2).start_world


def test_consecutive_seeds_without_list():
    cfg = CollectConfig(first_seed=100, episodes=3)
    assert [plan_episode(cfg, i).seed for i in range(3)] == [100, 101, 102]


def test_start_goal_respect_area_distance_altitude_and_heading():
    sg = StartGoalConfig(min_distance_m=25.0, max_distance_m=30.0)
    cfg = CollectConfig(start_goal=sg, episodes=200)
    for i in range(200):
        ep = plan_episode(cfg, i)
        s, g = np.array(ep.start_world), np.array(ep.goal_world)
        for p in (s, g):
            assert -18.0 <= p[0] <= 18.0 and -18.0 <= p[1] <= 18.0
            assert 1.0 <= p[2] <= 2.0
        d = np.linalg.norm((g - s)[:2])
        assert 25.0 - 1e-9 <= d <= 30.0 + 1e-9
        heading = np.arctan2(g[1] - s[1], g[0] - s[0])
        assert abs(np.angle(np.exp(1j * (heading - ep.start_yaw_rad)))) < 1e-9


def test_stop_after_episodes_or_samples():
    stop = StopCondition(CollectConfig(episodes=5, max_samples=100))
    assert stop.done(4, 99) == (False, "")
    assert stop.done(5, 0)[0]
    done, why = stop.done(1, 100)
    assert done and "max_samples=100" in why


def test_episode_log_round_trip_and_append_after_reopen(tmp_path):
    path = tmp_path / "episodes.csv"
    a = EpisodeOutcome(0, 3, "goal_reached", "goal reached", 12.5, 40)
    b = EpisodeOutcome(1, 4, "collision", "collision with box 17 at t=3.2 s", 3.2, 9)
    log = EpisodeLog(path)
    log.append(a)
    log.close()
    log = EpisodeLog(path)
    log.append(b)
    log.close()
    assert EpisodeLog.read(path) == [a, b]


@pytest.mark.parametrize(
    "yaml_text, message",
    [
        ("episodes: 0\n", "episodes"),
        ("episdoes: 3\n", "episdoes"),
        (
            "start_goal: {min_distance_m: 40, max_distance_m: 30}\n",
            "min_distance_m=40.0 > max_distance_m=30.0",
        ),
        ("start_goal: {min_distance_m: 60, max_distance_m: 70}\n", "does not fit"),
    ],
)
def test_bad_config_names_the_key(tmp_path, yaml_text, message):
    p = tmp_path / "collect.yaml"
    p.write_text(yaml_text)
    with pytest.raises(ValueError, match=message):
        load_collect_config(p)


def test_missing_config_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_collect_config(tmp_path / "nope.yaml")

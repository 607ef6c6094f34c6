"""The engine's batched policy rounds (quad_engine::PolicyVec::RunTorch, issue 32): a slot whose previous
decision ran the recovery gets its turned goals answered in the round's batched pass, and flying episodes
together gives each the outcome and verdicts it has flown alone. A seeded random policy: every proposal is
refused, so every decision runs the recovery (about 15 s)."""

from __future__ import annotations

import pytest

from quad_il.collection.episodes import StartGoalConfig, plan_eval_episodes
from quad_il.evaluation.tiers import render_tier_config
from quad_il.learning.config import load_config
from quad_il.tools import config_overlay
from quad_il.tools.repo import repo_root

ROOT = repo_root()
SKIPS = {"no_goal", "no_odometry", "bad_input", "stale_odometry", "goal_reached", "rate_limited"}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from quad_il.engine import native
    from quad_il.inference.random_policy import export_random_policy

    d = tmp_path_factory.mktemp("policy_vec")
    cfg = load_config([ROOT / "config" / "train.yaml"])
    policy_file = export_random_policy(
        d / "random.ts", cfg.model, cfg.data.shards.num_ctrl_pts, cfg.data.shards.horizon_s, 0, True
    )
    tier_yaml = d / "shield.yaml"
    tier_yaml.write_text(render_tier_config(ROOT / "config" / "policy.yaml", "shield"))
    e = native()
    configs = e.load_configs(
        *(
            str(config_overlay.resolve(ROOT / "config" / f"{n}.yaml"))
            for n in ("sim", "planner", "tracker", "vehicle")
        )
    )
    specs = plan_eval_episodes([9000, 9001], 2, StartGoalConfig())
    tuples = [(s.index, s.seed, s.start_world, s.start_yaw_rad, s.goal_world) for s in specs]
    torch_policy = e.TorchPolicy(str(policy_file))
    policy_cfg = e.load_policy_config(str(tier_yaml))
    e.configure_torch_threads(1)

    def fly(slots: int, which: list[int]):
        results: dict[int, dict] = {}
        vec = e.PolicyVec(configs, policy_cfg, torch_policy.meta, slots, False)
        vec.run_torch(
            torch_policy,
            [tuples[i] for i in which],
            10.0,
            4.0,
            lambda k, r, _labels: results.__setitem__(which[k], r),
        )
        return vec, results

    return fly


def _decisions(result: dict) -> int:
    return sum(int(n) for k, n in result["counts"].items() if k not in SKIPS)


def test_turned_goals_after_a_refusal_join_the_rounds_pass(setup) -> None:
    vec, results = setup(2, [0, 1])
    assert sorted(results) == [0, 1]
    decisions = sum(_decisions(r) for r in results.values())
    assert decisions == vec.batched_decisions > 2
    assert "accepted" not in {k for r in results.values() for k in r["counts"]}  # the random policy
    # Each episode's first refusal asks the network in a pass of its own; every later decision follows a
    # refusal, so its turned goals were in the round's pass and it needs no pass of its own.
    assert vec.recovery_passes == 2
    assert vec.speculated_decisions == decisions - 2
    assert vec.forward_passes < decisions


def test_episodes_flown_together_equal_episodes_flown_alone(setup) -> None:
    _, together = setup(2, [0, 1])
    for i in (0, 1):
        _, alone = setup(1, [i])
        for key in ("outcome", "reason", "counts", "steps", "sim_s"):
            assert alone[i][key] == together[i][key], (i, key)

"""Gymnasium environments on the rollout engine (issue 32, docs/engine.md, "Gymnasium").

    env = quad_il.engine.make_env(seed=0)                    # a gymnasium.Env
    venv = quad_il.engine.make_vec_env(8, seed=0)            # a gymnasium.vector.VectorEnv (one batch)

One episode is one keyed evaluation episode (quad_il.evaluation.runner's: take-off, then the goal): episode i
of an environment made with `seed` flies world seed `seed + i` with the start and goal the evaluation draws
for (world seed, i), so the same seed gives the same episodes whatever the number of environments (vector
env k starts at episode k and steps by num_envs). `reset(options={"index": i, "world_seed": w})` picks an
episode.

- observation: {"depth": (H, W) float32 in [0, 1], the network's depth input; "state": (13,) float32, the
  network's state vector (position, velocity, attitude, goal; config/train.yaml's frame and scales);
  "goal": (3,) float64, the goal in the world frame}. H, W and the state come from the policy's metadata
  (`policy=` an exported policy.ts) or, without one, from config/train.yaml's model.
- action: the network's flat output (network_output_dim float32): the B-spline control points in the
  training representation, then the hypotheses' logits if the model has several. The one C++ decider
  (quad_policy, the tier of `policy_config`: config/policy.yaml by default) judges it and the tracker flies
  what it sends, exactly as in the C++ policy node.
- reward: metres of progress toward the goal since the last decision, +10 at the goal, -10 at a collision.
- terminated: goal reached or collision; truncated: the episode's sim-time limit (or a failed take-off).
- info: "label" (the expert in labeller mode from the same state: {"ok", "knots", "ctrl_pts", "reason"}),
  "decision" (what the decider did: action, reason, verdict, accepted), "outcome" and "reason" at the end,
  "result" (the evaluation's measures) at the end.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from quad_il.collection.episodes import StartGoalConfig, eval_episode, load_collect_config
from quad_il.engine import native
from quad_il.tools import config_overlay
from quad_il.tools.repo import repo_root

GOAL_REWARD = 10.0
COLLISION_REWARD = -10.0
DEFAULTS: dict[str, Any] = {
    "policy": None,  # an exported policy.ts: its metadata fixes the spaces (else config/train.yaml's model)
    "policy_config": "config/policy.yaml",
    "sim_config": "config/sim.yaml",
    "planner_config": "config/planner.yaml",  # the labeller's
    "tracker_config": "config/tracker.yaml",
    "vehicle_config": "config/vehicle.yaml",
    "collect_config": "config/collect.yaml",  # start/goal sampling
    "train_config": "config/train.yaml",
    "labeller": True,
    "takeoff_timeout_s": 15.0,
    "episode_timeout_s": 60.0,
}


def _path(text: str | None) -> str | None:
    if text is None:
        return None
    p = Path(text)
    return str(p if p.is_absolute() else repo_root() / p)


def _options(overrides: dict[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(overrides) - set(DEFAULTS))
    if unknown:
        raise TypeError(f"unknown engine environment option(s) {unknown}; known: {sorted(DEFAULTS)}")
    return {**DEFAULTS, **overrides}


def _meta(o: dict[str, Any]):
    e = native()
    if o["policy"]:
        return e.TorchPolicy(_path(o["policy"])).meta
    from quad_il.learning.config import load_config
    from quad_il.learning.export import policy_metadata
    from quad_il.learning.model import Policy

    cfg = load_config([_path(o["train_config"])])
    net = Policy(cfg.model, cfg.data.shards.num_ctrl_pts, cfg.data.shards.horizon_s)
    text = json.dumps(policy_metadata(net, cfg.model.model_dump(mode="json")))
    return e.parse_policy_meta(text, o["train_config"])


class _Engine:
    """The native PolicyVec and what every environment over it shares."""

    def __init__(self, num_envs: int, o: dict[str, Any]) -> None:
        e = native()
        self.o = o
        self.meta = _meta(o)
        configs = e.load_configs(
            str(config_overlay.resolve(_path(o["sim_config"]))),
            str(config_overlay.resolve(_path(o["planner_config"]))),
            _path(o["tracker_config"]),
            _path(o["vehicle_config"]),
        )
        policy_cfg = e.load_policy_config(_path(o["policy_config"]))
        self.vec = e.PolicyVec(configs, policy_cfg, self.meta, num_envs, bool(o["labeller"]))
        self.start_goal: StartGoalConfig = load_collect_config(_path(o["collect_config"])).start_goal
        m = self.meta
        self.observation_space = spaces.Dict(
            {
                "depth": spaces.Box(0.0, 1.0, (m.input_height, m.input_width), np.float32),
                "state": spaces.Box(-np.inf, np.inf, (13,), np.float32),
                "goal": spaces.Box(-np.inf, np.inf, (3,), np.float64),
            }
        )
        self.action_space = spaces.Box(-np.inf, np.inf, (m.network_output_dim,), np.float32)

    def spec(self, index: int, world_seed: int):
        s = eval_episode(world_seed, index, self.start_goal)
        return (s.index, s.seed, s.start_world, s.start_yaw_rad, s.goal_world)

    def start(self, slot: int, index: int, world_seed: int) -> None:
        self.vec.reset(
            slot, self.spec(index, world_seed), self.o["takeoff_timeout_s"], self.o["episode_timeout_s"]
        )

    def observe(self, slot: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        r = self.vec.request(slot)
        obs = {
            "depth": np.clip(r["depth"], 0.0, 1.0),
            "state": r["state"],
            "goal": np.asarray(r["goal"], dtype=np.float64),
        }
        label = {
            "ok": bool(r["has_label"]),
            "knots": np.asarray(r["label_knots"], dtype=np.float64),
            "ctrl_pts": r["label_ctrl_pts"],
            "reason": r["label_reason"],
        }
        return obs, {"label": label, "stamp_s": r["stamp_s"], "p_world_body": np.asarray(r["p_world_body"])}

    def blank(self) -> dict[str, np.ndarray]:
        m = self.meta
        return {
            "depth": np.zeros((m.input_height, m.input_width), np.float32),
            "state": np.zeros(13, np.float32),
            "goal": np.zeros(3, np.float64),
        }


class EngineEnv(gym.Env):
    """One keyed evaluation episode of the policy at a time (see the module docstring)."""

    metadata = {"render_modes": []}

    def __init__(self, seed: int = 0, _engine: _Engine | None = None, **overrides: Any) -> None:
        self._e = _engine or _Engine(1, _options(overrides))
        self.observation_space = self._e.observation_space
        self.action_space = self._e.action_space
        self._seed = int(seed)
        self._next_index = 0
        self._dist = 0.0
        self._goal = np.zeros(3)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._seed, self._next_index = int(seed), 0
        options = options or {}
        index = int(options.get("index", self._next_index))
        world_seed = int(options.get("world_seed", self._seed + index))
        self._next_index = index + 1
        self._e.start(0, index, world_seed)
        obs, info = self._advance()
        info.update({"index": index, "world_seed": world_seed})
        return obs, info

    def _advance(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if self._e.vec.advance(0):
            obs, info = self._e.observe(0)
            self._goal = obs["goal"]
            self._dist = float(np.linalg.norm(info["p_world_body"] - self._goal))
            return obs, info
        return self._e.blank(), {}

    def step(self, action):
        vec = self._e.vec
        if vec.done(0):
            raise RuntimeError("step() after the episode ended: call reset()")
        decision = vec.decide(0, np.asarray(action, dtype=np.float32))
        dist_before = self._dist
        obs, info = self._advance()
        info["decision"] = decision
        reward, terminated, truncated = 0.0, False, False
        if vec.done(0):
            result = vec.result(0)
            info.update({"outcome": result["outcome"], "reason": result["reason"], "result": result})
            terminated = result["outcome"] in ("goal_reached", "collision")
            truncated = not terminated
            reward += GOAL_REWARD if result["outcome"] == "goal_reached" else 0.0
            reward += COLLISION_REWARD if result["outcome"] == "collision" else 0.0
        else:
            reward += dist_before - self._dist
        return obs, float(reward), terminated, truncated, info


def make_env(seed: int = 0, **overrides: Any) -> EngineEnv:
    """A gymnasium.Env of the engine (options: quad_il.engine.gym_env.DEFAULTS)."""
    return EngineEnv(seed=seed, **overrides)


class EngineVecEnv(gym.vector.VectorEnv):
    """num_envs episodes in one PolicyVec: step() decides every environment's frame, then advances them all to
    their next decisions; the caller's network runs once per step on the whole batch. An environment whose
    episode ended is reset at once to its next episode (the final observation and info of the ended one in
    info["final_obs"] / info["final_info"], Gymnasium 1.0's same-step autoreset)."""

    metadata = {"autoreset_mode": "same-step"}

    def __init__(self, num_envs: int, seed: int = 0, **overrides: Any) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs {num_envs}: must be >= 1")
        self._e = _Engine(num_envs, _options(overrides))
        self.num_envs = num_envs
        self.single_observation_space = self._e.observation_space
        self.single_action_space = self._e.action_space
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self._seed = int(seed)
        self._index = list(range(num_envs))
        self._obs = [self._e.blank() for _ in range(num_envs)]
        self._dist = np.zeros(num_envs)

    def _start(self, k: int) -> None:
        self._e.start(k, self._index[k], self._seed + self._index[k])

    def _collect(self, k: int) -> dict[str, Any]:
        obs, info = self._e.observe(k)
        self._obs[k] = obs
        self._dist[k] = float(np.linalg.norm(info["p_world_body"] - obs["goal"]))
        return info

    def _batch(self) -> dict[str, np.ndarray]:
        return {key: np.stack([o[key] for o in self._obs]) for key in ("depth", "state", "goal")}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._seed = int(seed)
        self._index = list(range(self.num_envs))
        for k in range(self.num_envs):
            self._start(k)
        infos: dict[str, Any] = {}
        waiting = set(self._e.vec.advance_all())
        for k in range(self.num_envs):
            info = self._collect(k) if k in waiting else {}
            infos = self._add_info(infos, info, k)
        return self._batch(), infos

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)
        vec = self._e.vec
        decisions = [vec.decide(k, actions[k]) if not vec.done(k) else None for k in range(self.num_envs)]
        before = self._dist.copy()
        waiting = set(vec.advance_all())
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        for k in range(self.num_envs):
            info: dict[str, Any] = {"decision": decisions[k]}
            if k in waiting:
                info.update(self._collect(k))
                rewards[k] = before[k] - self._dist[k]
            else:
                result = vec.result(k)
                terminated[k] = result["outcome"] in ("goal_reached", "collision")
                truncated[k] = not terminated[k]
                rewards[k] = {"goal_reached": GOAL_REWARD, "collision": COLLISION_REWARD}.get(
                    result["outcome"], 0.0
                )
                info.update({"outcome": result["outcome"], "reason": result["reason"], "result": result})
                info["final_obs"] = self._obs[k]
                # Same-step autoreset: this environment's next episode.
                self._index[k] += self.num_envs
                self._start(k)
                if vec.advance(k):
                    info.update(self._collect(k))
            infos = self._add_info(infos, info, k)
        return self._batch(), rewards, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self._e = None  # type: ignore[assignment]


def make_vec_env(num_envs: int, seed: int = 0, **overrides: Any) -> EngineVecEnv:
    """A gymnasium.vector.VectorEnv of num_envs engine environments stepped as one batch."""
    return EngineVecEnv(num_envs, seed=seed, **overrides)

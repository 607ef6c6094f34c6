"""The rollout engine (issue 32, docs/engine.md): keyed episodes of the simulator, tracker, expert and
collector stepped in-process by the C++ module quad_engine_py, exactly as collect.launch connects the nodes.

    python -m quad_il.engine.collect --help      # expert demonstrations, any number of workers, local or Ray
    env = quad_il.engine.make_env(seed=0)        # Gymnasium (quad_il.engine.gym_env)
    python -m quad_il.engine.collect --help
"""

from __future__ import annotations


class EngineNotBuiltError(ImportError):
    """The C++ module quad_engine_py is not importable (the workspace is not built or not sourced)."""


def native():
    """The C++ module quad_engine_py (built by catkin into devel/lib/python3/dist-packages)."""
    try:
        import quad_engine_py
    except ImportError as exc:
        raise EngineNotBuiltError(
            f"the rollout engine's C++ module quad_engine_py cannot be imported ({exc}): build the workspace "
            "(bash scripts/build.sh) and `source scripts/env.sh`"
        ) from None
    return quad_engine_py


def make_env(seed: int = 0, **overrides):
    """A gymnasium.Env of the engine (quad_il.engine.gym_env)."""
    from quad_il.engine.gym_env import make_env as make

    return make(seed=seed, **overrides)


def make_vec_env(num_envs: int, seed: int = 0, **overrides):
    """A gymnasium.vector.VectorEnv of num_envs engine environments, one batch (quad_il.engine.gym_env)."""
    from quad_il.engine.gym_env import make_vec_env as make

    return make(num_envs, seed=seed, **overrides)

"""The C++ inference core (quad_policy), bound with pybind11: the decider, the safety layer, the trajectories,
the policy config loader and the input checks exist once, in C++ (docs/inference.md, "One implementation").
Python keeps only the network's forward pass and its preprocessing (quad_il.inference.policy).

The extension `quad_policy_py` is built by catkin with quad_policy (scripts/build.sh) into
devel/lib/python3/dist-packages, which `source scripts/env.sh` puts on the path."""

from __future__ import annotations

try:
    import quad_policy_py as _core
except ImportError as e:  # pragma: no cover - depends on the build
    raise ImportError(
        f"quad_policy_py (the C++ inference core's bindings) is not importable ({e}): build the workspace "
        "(bash scripts/build.sh) and `source scripts/env.sh`"
    ) from None

CameraModel = _core.CameraModel
Decision = _core.Decision
KeepingConfig = _core.KeepingConfig
PolicyConfigError = _core.ConfigError  # a ValueError naming the file, the key and the value
PolicyDecider = _core.PolicyDecider
PolicyFormatError = _core.PolicyFormatError  # a ValueError naming the policy file and the problem
PolicyMeta = _core.PolicyMeta
PolicyNodeConfig = _core.PolicyNodeConfig
RecoveryConfig = _core.RecoveryConfig
RefusalConfig = _core.RefusalConfig
SafetyConfig = _core.SafetyConfig
SafetyResult = _core.SafetyResult
UniformBspline = _core.UniformBspline
braking_trajectory = _core.braking_trajectory
check_trajectory = _core.check_trajectory
depth_layout_problem = _core.depth_layout_problem
depth_size_problem = _core.depth_size_problem
parse_policy_meta = _core.parse_policy_meta
safety_sample_times = _core.safety_sample_times
state_problem = _core.state_problem
trajectory_in_view = _core.trajectory_in_view
VERDICT_LABELS: tuple[str, ...] = tuple(_core.verdict_labels())  # index: the verdict's number

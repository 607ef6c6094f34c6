"""The imitation-learning manager: one YAML file drives rounds of collection, training and evaluation as child
processes, stopped with POSIX signals and resumable after an interruption (docs/imitation_learning.md)."""

from quad_il.manager.config import ConfigError, ManagerConfig, load_config
from quad_il.manager.runner import ManagerError, PipelineRunner
from quad_il.manager.state import RunLayout, RunState, Status
from quad_il.manager.supervisor import ChildSpec, Escalation, Supervisor

__all__ = [
    "ChildSpec",
    "ConfigError",
    "Escalation",
    "ManagerConfig",
    "ManagerError",
    "PipelineRunner",
    "RunLayout",
    "RunState",
    "Status",
    "Supervisor",
    "load_config",
]

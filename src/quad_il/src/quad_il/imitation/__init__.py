"""Interactive imitation learning, ROS-free: BC, DAgger, HG-DAgger, EIL and MEGA-DAgger behind one callback.

The rospy collector (`ros_collector`, imported only in ROS processes) pairs each depth frame with the plans
the learner and the expert(s) made from it (`pairing.StampPairer`) and hands each pair to
`ImitationLearnerBase.step`, whose overridable `callback` decides who flies and what is recorded
(docs/imitation_learning.md).
"""

from quad_il.imitation.bspline import (
    DeviationParams,
    SplineAction,
    SplineError,
    ctrl_rms_distance,
    deviation_m,
    sampled_rms_distance,
)
from quad_il.imitation.config import AlgorithmConfig, RoundAlgorithmConfig
from quad_il.imitation.gate import GateEvent, GateParams, HysteresisGate
from quad_il.imitation.learners import (
    BCLearner,
    DAggerLearner,
    EILLearner,
    HGDAggerLearner,
    ImitationLearnerBase,
    MegaDAggerLearner,
    make_learner,
    resolve_conflicts,
)
from quad_il.imitation.safety import PointCloudClearance, check_label_safety, label_score
from quad_il.imitation.schedules import BetaSchedule
from quad_il.imitation.types import (
    Controller,
    Decision,
    EpisodeOutcome,
    ImitationError,
    Observation,
    Pair,
    Partition,
    Record,
)

__all__ = [
    "AlgorithmConfig",
    "BCLearner",
    "BetaSchedule",
    "Controller",
    "DAggerLearner",
    "Decision",
    "DeviationParams",
    "EILLearner",
    "EpisodeOutcome",
    "GateEvent",
    "GateParams",
    "HGDAggerLearner",
    "HysteresisGate",
    "ImitationError",
    "ImitationLearnerBase",
    "MegaDAggerLearner",
    "Observation",
    "Pair",
    "Partition",
    "PointCloudClearance",
    "Record",
    "RoundAlgorithmConfig",
    "SplineAction",
    "SplineError",
    "check_label_safety",
    "ctrl_rms_distance",
    "deviation_m",
    "label_score",
    "make_learner",
    "resolve_conflicts",
    "sampled_rms_distance",
]

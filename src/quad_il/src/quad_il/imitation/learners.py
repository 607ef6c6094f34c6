"""The learner algorithms behind one overridable callback (thesis section 3.8: "a variety of interactive
imitation learning algorithms ... can be implemented in the pipeline by overriding the callback function").

`ImitationLearnerBase.step(pair)` receives one observation with the learner's plan and every expert's plan
made from exactly that observation (lockstep pairing, `pairing.StampPairer`), and returns a `Decision`: who
flies, which plan is executed, and which records are written. Subclasses override `callback` (and optionally
`_on_start_episode`, `_finish_episode`). Everything here is ROS-free and deterministic given the seeded
`numpy.random.Generator`.

- BC: the expert flies; every step is recorded with the expert's label (DEMO).
- DAgger: the expert flies with probability beta_i, else the learner; every step gets the expert's label
  (DEMO).
- HG-DAgger: the learner flies, the expert while the gate is open; only expert-controlled steps are recorded
  (INTERVENTION).
- EIL: as HG-DAgger, plus the learner's plans before and at each onset (BAD) and on the other learner steps
  (GOOD).
- MEGA-DAgger: the learner flies; during an intervention the best safe expert plan (gate expert chosen per
  episode); the best-scoring safe label is recorded; unsafe labels and labels that led into a collision are
  dropped; conflicts are resolved by score at the end of the episode.
"""

from __future__ import annotations

import abc
import collections
import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from quad_il.imitation.bspline import DeviationParams, SplineAction, deviation_m, horizon_times
from quad_il.imitation.config import (
    BCConfig,
    DAggerConfig,
    EILConfig,
    HGDAggerConfig,
    MegaConflictConfig,
    MegaDAggerConfig,
    RoundAlgorithmConfig,
)
from quad_il.imitation.gate import GateEvent, GateParams, HysteresisGate
from quad_il.imitation.safety import (
    ClearanceMap,
    SafetyParams,
    ScoreParams,
    check_label_safety,
    label_score,
)
from quad_il.imitation.types import (
    Controller,
    Decision,
    EpisodeOutcome,
    ImitationError,
    LearnerStats,
    Observation,
    Pair,
    Partition,
    Record,
)


class ImitationLearnerBase(abc.ABC):
    """Base of every learner algorithm: episode bookkeeping, statistics, and the callback contract."""

    name = "base"

    def __init__(self, round_index: int, rng: np.random.Generator) -> None:
        if round_index < 0:
            raise ImitationError(f"round_index must be >= 0, got {round_index}")
        self.round_index = int(round_index)
        self.rng = rng
        self.stats = LearnerStats()
        self.episode_id: int | None = None
        self.episodes_started = 0

    # ---- episode protocol ----
    def start_episode(self, episode_id: int) -> None:
        if self.episode_id is not None:
            raise ImitationError(f"start_episode({episode_id}) while episode {self.episode_id} is still open")
        self.episode_id = int(episode_id)
        self._on_start_episode()
        self.episodes_started += 1

    def step(self, pair: Pair) -> Decision:
        """Validate, run the callback, update the statistics."""
        if self.episode_id is None:
            raise ImitationError("step() before start_episode()")
        if pair.obs.episode_id != self.episode_id:
            raise ImitationError(
                f"pair from episode {pair.obs.episode_id} fed to open episode {self.episode_id}"
            )
        if pair.expert is None:
            self.stats.missing_expert += 1
        if pair.learner is None:
            self.stats.missing_learner += 1
        decision = self.callback(pair)
        if (decision.controller is Controller.NONE) != (decision.action is None):
            raise ImitationError(
                f"{self.name}: decision flies {decision.controller} with action {decision.action}"
            )
        self.stats.steps += 1
        if decision.controller is Controller.EXPERT:
            self.stats.steps_expert += 1
        elif decision.controller is Controller.LEARNER:
            self.stats.steps_learner += 1
        else:
            self.stats.steps_none += 1
        self.stats.count_records(decision.records)
        return decision

    def end_episode(self, outcome: EpisodeOutcome) -> tuple[Record, ...]:
        """Close the episode; returns the records held back until its end (EIL's pending window,
        MEGA-DAgger)."""
        if self.episode_id is None:
            raise ImitationError("end_episode() without an open episode")
        records = tuple(self._finish_episode(outcome))
        self.stats.count_records(records)
        self.episode_id = None
        return records

    # ---- to override ----
    @abc.abstractmethod
    def callback(self, pair: Pair) -> Decision:
        """Decide who flies on this pair and what is recorded."""

    def _on_start_episode(self) -> None:  # noqa: B027 (optional hook, empty by default)
        """Hook: per-episode state (e.g. DAgger's per-episode coin, MEGA-DAgger's gate expert)."""

    def _finish_episode(self, outcome: EpisodeOutcome) -> Sequence[Record]:
        """Hook: records released at the end of the episode."""
        del outcome
        return ()

    # ---- helpers ----
    def _record(
        self,
        obs: Observation,
        label: SplineAction,
        partition: Partition,
        source: str,
        controller: Controller,
        **kwargs: object,
    ) -> Record:
        return Record(
            obs=obs,
            label=label,
            partition=partition,
            source=source,
            controller=controller,
            round_index=self.round_index,
            **kwargs,  # type: ignore[arg-type]
        )


def _fly(preferred: Controller, pair: Pair) -> tuple[Controller, SplineAction | None]:
    """The preferred controller's plan, else the other's, else nothing (the tracker holds the last plan)."""
    expert, learner = pair.expert, pair.learner
    order = (
        [(Controller.EXPERT, expert), (Controller.LEARNER, learner)]
        if preferred is Controller.EXPERT
        else [(Controller.LEARNER, learner), (Controller.EXPERT, expert)]
    )
    for controller, action in order:
        if action is not None:
            return controller, action
    return Controller.NONE, None


class BCLearner(ImitationLearnerBase):
    """Behaviour cloning: the expert flies and labels every step; the learner is not consulted."""

    name = "bc"

    def callback(self, pair: Pair) -> Decision:
        expert = pair.expert
        if expert is None:
            return Decision(Controller.NONE, None)
        rec = self._record(pair.obs, expert, Partition.DEMO, pair.primary_expert, Controller.EXPERT)
        return Decision(Controller.EXPERT, expert, (rec,), expert_name=pair.primary_expert)


class DAggerLearner(ImitationLearnerBase):
    """DAgger (Ross et al. 2011): the mixture beta*expert + (1-beta)*learner flies; the expert labels every
    step.

    mixing "per_step" flips a beta-coin on each step, "per_episode" once per episode. If the chosen controller
    has no plan the other one flies. Steps without an expert plan are not recorded (no label).
    """

    name = "dagger"

    def __init__(
        self, round_index: int, rng: np.random.Generator, beta: float, mixing: str = "per_step"
    ) -> None:
        super().__init__(round_index, rng)
        if not 0.0 <= beta <= 1.0:
            raise ImitationError(f"beta must be in [0, 1], got {beta}")
        if mixing not in ("per_step", "per_episode"):
            raise ImitationError(f"mixing must be per_step or per_episode, got {mixing!r}")
        self.beta = float(beta)
        self.mixing = mixing
        self._episode_expert = False

    def _coin(self) -> bool:
        # Always draw, also for beta in {0, 1}, so the random stream does not depend on beta.
        return bool(self.rng.random() < self.beta)

    def _on_start_episode(self) -> None:
        self._episode_expert = self._coin() if self.mixing == "per_episode" else False

    def callback(self, pair: Pair) -> Decision:
        expert_turn = self._coin() if self.mixing == "per_step" else self._episode_expert
        controller, action = _fly(Controller.EXPERT if expert_turn else Controller.LEARNER, pair)
        records: tuple[Record, ...] = ()
        if pair.expert is not None:
            records = (self._record(pair.obs, pair.expert, Partition.DEMO, pair.primary_expert, controller),)
        return Decision(
            controller,
            action,
            records,
            expert_name=pair.primary_expert if controller is Controller.EXPERT else None,
        )


class _GatedLearner(ImitationLearnerBase):
    """Shared gate logic of HG-DAgger, EIL and MEGA-DAgger (see gate.py).

    Per step: deviation d between the learner's plan and the gate expert's plan (d = inf without a learner
    plan); the gate updates on d; while it is open the expert flies, otherwise the learner. Without a plan
    from the gate expert nothing can be judged: the gate keeps its state, the learner flies if it can, nothing
    is recorded.
    """

    def __init__(
        self, round_index: int, rng: np.random.Generator, gate: GateParams, deviation: DeviationParams
    ) -> None:
        super().__init__(round_index, rng)
        self.gate = HysteresisGate(gate)
        self.deviation_params = deviation

    def _on_start_episode(self) -> None:
        self.gate.reset()

    def _gate_expert(self, pair: Pair) -> str:
        return pair.primary_expert

    def callback(self, pair: Pair) -> Decision:
        gate_name = self._gate_expert(pair)
        expert = pair.experts[gate_name]
        learner = pair.learner
        if expert is None:
            if learner is None:
                return Decision(Controller.NONE, None, intervening=self.gate.intervening)
            return Decision(Controller.LEARNER, learner, intervening=self.gate.intervening)
        dev = (
            math.inf
            if learner is None
            else deviation_m(learner, expert, pair.obs.stamp_s, self.deviation_params)
        )
        event = self.gate.update(dev)
        if event is GateEvent.ONSET:
            self.stats.interventions += 1
        if self.gate.intervening:
            records, action, name = self._intervention_step(pair, gate_name, dev, event is GateEvent.ONSET)
            return Decision(Controller.EXPERT, action, records, name, True, dev)
        if learner is None:  # unreachable: d = inf always opens the gate
            raise ImitationError("internal: gate closed without a learner plan")
        return Decision(Controller.LEARNER, learner, self._learner_step(pair, dev), None, False, dev)

    def _intervention_step(
        self, pair: Pair, gate_name: str, dev: float, onset: bool
    ) -> tuple[tuple[Record, ...], SplineAction, str]:
        del onset
        expert = pair.experts[gate_name]
        if expert is None:  # unreachable: callback() returns early without a gate-expert plan
            raise ImitationError(f"internal: intervention without a plan from {gate_name!r}")
        rec = self._record(
            pair.obs,
            expert,
            Partition.INTERVENTION,
            gate_name,
            Controller.EXPERT,
            deviation_m=dev,
            contrast=pair.learner,
        )
        return (rec,), expert, gate_name

    def _learner_step(self, pair: Pair, dev: float) -> tuple[Record, ...]:
        del pair, dev
        return ()


class HGDAggerLearner(_GatedLearner):
    """HG-DAgger (Kelly et al. 2019): only the expert-controlled steps are recorded, with the expert's
    label."""

    name = "hg_dagger"


class EILLearner(_GatedLearner):
    """Expert Intervention Learning (Spencer et al. 2022): the HG-DAgger gate plus implicit feedback.

    Partitions (the paper's good-enough set G, its complement, and the intervention set I):
      INTERVENTION  expert in control: (s, a_expert), with the learner's plan as `contrast`;
      BAD           the learner's (s, a_learner) on the `bad_window_steps` learner-controlled steps right
      before an
                    intervention onset and on the onset step itself (the expert judged them bad by
                    intervening); also the pending steps of an episode that ends in a collision while the
                    learner flies;
      GOOD          every other learner-controlled step (no intervention followed: good enough).
    A learner step is therefore emitted `bad_window_steps` steps late (or at the end of the episode).
    """

    name = "eil"

    def __init__(
        self,
        round_index: int,
        rng: np.random.Generator,
        gate: GateParams,
        deviation: DeviationParams,
        bad_window_steps: int = 3,
        record_good: bool = True,
    ) -> None:
        super().__init__(round_index, rng, gate, deviation)
        if bad_window_steps < 0:
            raise ImitationError(f"bad_window_steps must be >= 0, got {bad_window_steps}")
        self.bad_window_steps = int(bad_window_steps)
        self.record_good = bool(record_good)
        self._pending: collections.deque[Record] = collections.deque()

    def _on_start_episode(self) -> None:
        super()._on_start_episode()
        self._pending.clear()

    def _learner_step(self, pair: Pair, dev: float) -> tuple[Record, ...]:
        if pair.learner is None:  # unreachable: learner steps have a learner plan
            raise ImitationError("internal: learner step without a learner plan")
        self._pending.append(
            self._record(
                pair.obs, pair.learner, Partition.GOOD, "learner", Controller.LEARNER, deviation_m=dev
            )
        )
        out: list[Record] = []
        while len(self._pending) > self.bad_window_steps:
            rec = self._pending.popleft()
            if self.record_good:
                out.append(rec)
        return tuple(out)

    def _intervention_step(
        self, pair: Pair, gate_name: str, dev: float, onset: bool
    ) -> tuple[tuple[Record, ...], SplineAction, str]:
        (rec,), action, name = super()._intervention_step(pair, gate_name, dev, onset)
        out: list[Record] = []
        if onset:
            out.extend(dataclasses.replace(r, partition=Partition.BAD) for r in self._pending)
            self._pending.clear()
            if pair.learner is not None:
                out.append(
                    self._record(
                        pair.obs, pair.learner, Partition.BAD, "learner", Controller.EXPERT, deviation_m=dev
                    )
                )
        out.append(rec)
        return tuple(out), action, name

    def _finish_episode(self, outcome: EpisodeOutcome) -> Sequence[Record]:
        pending = list(self._pending)
        self._pending.clear()
        if outcome.collided:
            return [dataclasses.replace(r, partition=Partition.BAD) for r in pending]
        return pending if self.record_good else []


# ---- MEGA-DAgger ----


def yaw_of(q_xyzw: np.ndarray) -> float:
    x, y, z, w = (float(v) for v in q_xyzw)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def observation_features(
    obs: Observation, depth_grid: tuple[int, int] = (6, 8), max_depth_m: float = 10.0
) -> np.ndarray:
    """Default observation descriptor for MEGA-DAgger's similarity matching (if obs.features is None).

    Yaw-only vehicle frame (docs/CONVENTIONS.md): unit goal direction (3), goal distance / 10 m clipped to 1,
    velocity / 3 m/s (3), and the depth image as block means over `depth_grid` cells, divided by max_depth_m
    and centred by -0.5 (so that free space and obstacles point in different directions for the cosine).
    Position is left out on purpose: the same view in another place of the world is the same observation to
    the policy.
    """
    yaw = yaw_of(obs.q_world_body)
    c, s = math.cos(yaw), math.sin(yaw)
    rot_t = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    g = rot_t @ (obs.goal_world - obs.p_world_body)
    g_norm = float(np.linalg.norm(g))
    g_dir = g / g_norm if g_norm > 1e-9 else np.zeros(3)
    v = rot_t @ obs.v_world / 3.0
    parts = [g_dir, [min(1.0, g_norm / 10.0)], v]
    if obs.depth_m is not None:
        d = np.nan_to_num(obs.depth_m.astype(np.float64), nan=max_depth_m, posinf=max_depth_m, neginf=0.0)
        d = np.clip(d, 0.0, max_depth_m)
        rows = np.array_split(np.arange(d.shape[0]), depth_grid[0])
        cols = np.array_split(np.arange(d.shape[1]), depth_grid[1])
        cells = [d[np.ix_(r, cc)].mean() if r.size and cc.size else max_depth_m for r in rows for cc in cols]
        parts.append(np.asarray(cells) / max_depth_m - 0.5)
    return np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1) for p in parts])


def _label_path_local(rec: Record, horizon_s: float, num_samples: int) -> np.ndarray:
    """The label's positions over the horizon in the observation's yaw-only frame (origin at the vehicle)."""
    t = horizon_times(rec.obs.stamp_s, horizon_s, num_samples)
    p = rec.label.positions(t) - rec.obs.p_world_body
    yaw = yaw_of(rec.obs.q_world_body)
    c, s = math.cos(yaw), math.sin(yaw)
    x = c * p[:, 0] + s * p[:, 1]
    y = -s * p[:, 0] + c * p[:, 1]
    return np.stack([x, y, p[:, 2]], axis=1)


@dataclasses.dataclass(frozen=True)
class ConflictResolution:
    kept: tuple[Record, ...]
    dropped: tuple[Record, ...]


def resolve_conflicts(records: Sequence[Record], cfg: MegaConflictConfig) -> ConflictResolution:
    """MEGA-DAgger's conflict resolution among labels of near-identical observations.

    Two records conflict when the cosine similarity of their observation features is >= cosine_threshold and
    their labels, compared in each observation's own vehicle frame over the horizon (sampled RMS), differ by
    more than label_distance_m. Greedy in order of decreasing score (ties: earlier record first; NaN scores
    last): a record is kept unless it conflicts with an already kept one. Kept records keep their input order.
    O(N * kept) vectorised; used per episode by the learner and on the aggregated dataset by the trainer.
    """
    n = len(records)
    if n == 0:
        return ConflictResolution((), ())
    feats = [r.obs.features if r.obs.features is not None else observation_features(r.obs) for r in records]
    dim = feats[0].shape[0]
    for i, f in enumerate(feats):
        if f.shape[0] != dim:
            raise ImitationError(f"record {i} has {f.shape[0]} observation features, record 0 has {dim}")
    mat = np.stack(feats)
    norms = np.linalg.norm(mat, axis=1, keepdims=True)
    unit = np.divide(mat, norms, out=np.zeros_like(mat), where=norms > 0.0)
    paths = np.stack([_label_path_local(r, cfg.horizon_s, cfg.num_samples) for r in records])
    scores = np.array([r.score if math.isfinite(r.score) else -math.inf for r in records])
    order = sorted(range(n), key=lambda i: (-scores[i], i))
    kept_idx: list[int] = []
    dropped_idx: list[int] = []
    for i in order:
        if kept_idx:
            k = np.asarray(kept_idx)
            sim = unit[k] @ unit[i]
            diff = paths[k] - paths[i]
            dist = np.sqrt(np.mean(np.sum(diff * diff, axis=2), axis=1))
            if np.any((sim >= cfg.cosine_threshold) & (dist > cfg.label_distance_m)):
                dropped_idx.append(i)
                continue
        kept_idx.append(i)
    kept_set = set(kept_idx)
    return ConflictResolution(
        tuple(records[i] for i in range(n) if i in kept_set),
        tuple(records[i] for i in sorted(dropped_idx)),
    )


class MegaDAggerLearner(_GatedLearner):
    """MEGA-DAgger (Sun et al. 2023) with several imperfect experts (e.g. planners with different parameters).

    - One gate expert per episode (round robin over episodes, or seeded random) decides interventions, as the
      human of HG-DAgger does.
    - On an intervention step every expert with a plan is a label candidate; candidates failing the
    clearance/CBF
      safety check are dropped; the best-scoring safe candidate is recorded and flown (if none is safe the
      gate expert's plan is flown and nothing is recorded).
    - At the end of the episode, if it ended in a collision, records within collision_window_s before the
      collision are dropped (those demonstrations led into it); then conflicts among the episode's records are
      resolved by score (`resolve_conflicts`).
    """

    name = "mega_dagger"

    def __init__(
        self,
        round_index: int,
        rng: np.random.Generator,
        cfg: MegaDAggerConfig,
        clearance: ClearanceMap,
    ) -> None:
        super().__init__(round_index, rng, cfg.gate.params(), cfg.gate.deviation.params())
        self.cfg = cfg
        self.clearance = clearance
        self.safety: SafetyParams = cfg.safety.params()
        self.score_params: ScoreParams = cfg.score.params()
        self.experts = list(cfg.experts)
        self._gate_name = self.experts[0]
        self._episode_records: list[Record] = []
        self.last_resolution = ConflictResolution((), ())

    def _on_start_episode(self) -> None:
        super()._on_start_episode()
        if self.cfg.gate_expert == "round_robin":
            self._gate_name = self.experts[self.episodes_started % len(self.experts)]
        else:
            self._gate_name = self.experts[int(self.rng.integers(len(self.experts)))]
        self._episode_records = []

    @property
    def gate_expert(self) -> str:
        return self._gate_name

    def _gate_expert(self, pair: Pair) -> str:
        missing = [e for e in self.experts if e not in pair.experts]
        if missing:
            raise ImitationError(f"pair lacks the configured experts {missing} (has {sorted(pair.experts)})")
        return self._gate_name

    def _intervention_step(
        self, pair: Pair, gate_name: str, dev: float, onset: bool
    ) -> tuple[tuple[Record, ...], SplineAction, str]:
        del onset
        best: Record | None = None
        for name in self.experts:
            action = pair.experts[name]
            if action is None:
                continue
            res = check_label_safety(action, pair.obs.stamp_s, self.clearance, self.safety)
            if not res.safe:
                self.stats.dropped_unsafe += 1
                continue
            score = label_score(
                action, pair.obs, res.min_clearance_m, self.safety.horizon_s, self.score_params
            )
            if best is None or score > best.score:
                best = self._record(
                    pair.obs,
                    action,
                    Partition.INTERVENTION,
                    name,
                    Controller.EXPERT,
                    deviation_m=dev,
                    contrast=pair.learner,
                    score=score,
                    min_clearance_m=res.min_clearance_m,
                )
        if best is None:
            fallback = pair.experts[gate_name]
            if fallback is None:  # unreachable: callback() returns early without a gate-expert plan
                raise ImitationError(f"internal: intervention without a plan from {gate_name!r}")
            return (), fallback, gate_name
        self._episode_records.append(best)
        return (), best.label, best.source

    def _finish_episode(self, outcome: EpisodeOutcome) -> Sequence[Record]:
        records = self._episode_records
        self._episode_records = []
        if outcome.collided and outcome.collision_time_s is not None:
            cutoff = outcome.collision_time_s - self.cfg.collision_window_s
            before = len(records)
            records = [r for r in records if r.obs.stamp_s < cutoff]
            self.stats.dropped_collision += before - len(records)
        res = resolve_conflicts(records, self.cfg.conflict)
        self.stats.dropped_conflict += len(res.dropped)
        self.last_resolution = res
        return res.kept


def make_learner(
    cfg: RoundAlgorithmConfig, rng: np.random.Generator, clearance: ClearanceMap | None = None
) -> ImitationLearnerBase:
    """The learner of one round. Without a learner policy yet (`expert_only`), every algorithm collects as
    BC."""
    algo = cfg.algorithm
    r = cfg.round_index
    if cfg.expert_only or isinstance(algo, BCConfig):
        return BCLearner(r, rng)
    if isinstance(algo, DAggerConfig):
        beta = cfg.beta if cfg.beta is not None else algo.beta.schedule().beta(r)
        return DAggerLearner(r, rng, beta, algo.beta.mixing)
    if isinstance(algo, HGDAggerConfig):
        return HGDAggerLearner(r, rng, algo.gate.params(), algo.gate.deviation.params())
    if isinstance(algo, EILConfig):
        return EILLearner(
            r, rng, algo.gate.params(), algo.gate.deviation.params(), algo.bad_window_steps, algo.record_good
        )
    if isinstance(algo, MegaDAggerConfig):
        if clearance is None:
            raise ImitationError("mega_dagger needs a clearance map (the world's occupied voxels)")
        return MegaDAggerLearner(r, rng, algo, clearance)
    raise ImitationError(f"unknown algorithm {algo!r}")

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
- DART: the expert flies, disturbed during seeded perturbation events (brake to rest, veer off its line);
  every N-th step gets the expert's clean label (DEMO). No learner needed.
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
    DARTConfig,
    DARTRangeConfig,
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
from quad_il.inference.core import braking_trajectory


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

    def algorithm_stats(self) -> dict[str, object]:
        """Hook: counters of the algorithm's own (the collector writes them to its manifest)."""
        return {}

    # ---- helpers ----
    def _without_collision_window(
        self, records: list[Record], outcome: EpisodeOutcome, window_s: float
    ) -> list[Record]:
        """An episode's records without those of its last window_s before a collision (the labels that led
        into it), counted in stats.dropped_collision; all of them when it did not collide."""
        if not outcome.collided or outcome.collision_time_s is None:
            return records
        cutoff = outcome.collision_time_s - window_s
        kept = [r for r in records if r.obs.stamp_s < cutoff]
        self.stats.dropped_collision += len(records) - len(kept)
        return kept

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


class DARTLearner(ImitationLearnerBase):
    """DART (Laskey et al., "DART: Noise Injection for Robust Imitation Learning", CoRL 2017): the expert
    flies and labels, and noise injected into what it executes makes the demonstrations visit states off its
    own path, where a learned policy's errors take it, each labelled with the expert's undisturbed plan.

    The noise here is a sequence of perturbation events in sim time (the learned policies fail stopped in
    front of boxes and heading into them, states the expert's own flights never show):
    - brake: the executed plan brings the vehicle to rest along its line of motion
      (`braking_trajectory`, deceleration at most brake_decel_mps2) and holds it there;
    - veer: the executed plan is the expert's plan turned about its start point by +-angle about the
      vertical, so the vehicle heads off the expert's line.
    A new plan is executed every execute_every_steps-th step, at each onset and end of an event, and outside
    events when the expert's newest plan departs from the one being flown by more than replan_deviation_m
    (the tracker flies the last one between: the labeller's plans, flown a frame each, would keep the vehicle
    slow). An event starts with probability 1 - exp(-rate dt) per step (dt: the time since the previous
    step) once min_gap_s has passed since the last one, first_after_s after the episode's first step, and
    farther than min_goal_distance_m from the goal; kind, duration and angle are drawn at onset. Every
    record_every_steps-th step with an expert plan is recorded (DEMO) with that plan as the label, inside
    events as outside; records are released at the episode's end, without those of the last
    collision_window_s before a collision.
    Randomness: a fixed number of draws per step and per onset from the seeded generator.
    """

    name = "dart"

    def __init__(self, round_index: int, rng: np.random.Generator, cfg: DARTConfig) -> None:
        super().__init__(round_index, rng)
        self.cfg = cfg
        self.event_counts = {"brake": 0, "veer": 0}
        self._reset_episode_state()

    def _reset_episode_state(self) -> None:
        self._first_stamp: float | None = None
        self._prev_stamp: float | None = None
        self._event: str | None = None  # "brake", "veer" or None
        self._event_end_s = -math.inf
        self._veer_rad = 0.0
        self._labelled_steps = 0
        self._since_sent: int | None = None  # steps since a plan was last executed (None: none yet)
        self._pending = False  # an event started or ended: a new plan is due until one is sent
        self._executed: SplineAction | None = None  # the plan being flown
        self._records: list[Record] = []  # this episode's, released at its end

    def _on_start_episode(self) -> None:
        self._reset_episode_state()

    def algorithm_stats(self) -> dict[str, object]:
        return {"events": dict(self.event_counts)}

    @property
    def event(self) -> str | None:
        """The perturbation running after the last step: "brake", "veer" or None."""
        return self._event

    def _draw(self, r: DARTRangeConfig) -> float:
        return float(r.low + (r.high - r.low) * self.rng.random())

    def _update_event(self, obs: Observation) -> None:
        t = obs.stamp_s
        if self._first_stamp is None:
            self._first_stamp = t
        dt = 0.0 if self._prev_stamp is None else max(t - self._prev_stamp, 0.0)
        self._prev_stamp = t
        if self._event is not None and t >= self._event_end_s:
            self._event = None
            self._pending = True  # the event's end: the expert's plan takes over at once
        u = float(self.rng.random())  # drawn on every step, so the stream does not depend on the state
        if self._event is not None:
            return
        cfg = self.cfg
        allowed = (
            t - self._first_stamp >= cfg.first_after_s
            and t - self._event_end_s >= cfg.min_gap_s
            and float(np.linalg.norm(obs.goal_world - obs.p_world_body)) > cfg.min_goal_distance_m
        )
        if not (allowed and u < 1.0 - math.exp(-cfg.event_rate_per_s * dt)):
            return
        if self.rng.random() < cfg.brake_probability:
            self._event = "brake"
            duration = self._draw(cfg.brake_duration_s)
        else:
            self._event = "veer"
            duration = self._draw(cfg.veer_duration_s)
            sign = 1.0 if self.rng.random() < 0.5 else -1.0
            self._veer_rad = sign * math.radians(self._draw(cfg.veer_angle_deg))
        self._event_end_s = t + duration
        self._pending = True
        self.event_counts[self._event] += 1

    def _brake(self, obs: Observation) -> SplineAction:
        traj = braking_trajectory(
            obs.p_world_body, obs.v_world, self.cfg.brake_decel_mps2, BRAKE_MIN_DURATION_S, obs.stamp_s
        )
        return SplineAction.uniform(traj.ctrl_world, traj.knot_dt_s, 3, obs.stamp_s)

    def callback(self, pair: Pair) -> Decision:
        self._update_event(pair.obs)
        expert = pair.expert
        if expert is not None:
            if self._labelled_steps % self.cfg.record_every_steps == 0:
                self._records.append(
                    self._record(pair.obs, expert, Partition.DEMO, pair.primary_expert, Controller.EXPERT)
                )
            self._labelled_steps += 1
        due = (
            self._pending
            or self._since_sent is None
            or self._since_sent + 1 >= self.cfg.execute_every_steps
            or self._expert_departs(pair)
        )
        action: SplineAction | None = None
        if due:
            if self._event == "brake":
                action = self._brake(pair.obs)
            elif expert is not None:
                action = turned_about_start(expert, self._veer_rad) if self._event == "veer" else expert
        if action is None:  # not due, or due without a plan (retried on the next step)
            if self._since_sent is not None and not due:
                self._since_sent += 1
            return Decision(Controller.NONE, None)
        self._since_sent = 0
        self._pending = False
        self._executed = action
        return Decision(Controller.EXPERT, action, expert_name=pair.primary_expert)

    def _expert_departs(self, pair: Pair) -> bool:
        """Outside events: the expert's newest plan departs from the plan being flown (it saw something)."""
        if self._event is not None or self.cfg.replan_deviation_m <= 0.0:
            return False
        if pair.expert is None or self._executed is None:
            return False
        d = deviation_m(pair.expert, self._executed, pair.obs.stamp_s, DART_DEVIATION)
        return d > self.cfg.replan_deviation_m

    def _finish_episode(self, outcome: EpisodeOutcome) -> Sequence[Record]:
        records, self._records = self._records, []
        records = self._without_collision_window(records, outcome, self.cfg.collision_window_s)
        return records


# Shortest braking trajectory of DART's brake events (s): from rest it is a hold of this length.
BRAKE_MIN_DURATION_S = 0.5
# How DART compares the expert's newest plan with the one being flown: sampled RMS over the next second.
DART_DEVIATION = DeviationParams("sampled_rms", 1.0, 11)


def turned_about_start(action: SplineAction, yaw_rad: float) -> SplineAction:
    """The plan turned by yaw_rad about the vertical through its start point (the position at its start
    time): same knots and timing, same start position, its velocity and shape rotated."""
    p0 = action.positions([action.start_time_s])[0]
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ctrl = (action.ctrl_pts_world - p0) @ rot.T + p0
    return SplineAction(ctrl, action.knots, action.order, action.start_time_s, action.traj_id)


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
        records = self._without_collision_window(records, outcome, self.cfg.collision_window_s)
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
    if isinstance(algo, DARTConfig):  # the expert flies: no learner policy needed
        return DARTLearner(r, rng, algo)
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

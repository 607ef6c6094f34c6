"""Pairing of observations with the plans made from them, by the depth frame's stamp (ROS-free).

In lockstep every consumer of a depth frame (the expert(s) and the learner policy) plans from that exact frame
and stamps its B-spline with the frame's stamp (`Bspline.start_time` = depth `header.stamp`,
docs/CONVENTIONS.md and issue 8), so a pair is complete when the observation and one plan per source with the
same stamp have arrived, in any order. A source that could not plan publishes nothing for that frame;
`flush_before` completes such pairs with `None` once a newer frame has been fully paired (the simulator does
not advance past a frame until every consumer acknowledged it, so a missing plan never arrives later).
Bounded: at most `max_pending` stamps are held; the oldest is evicted (and counted) beyond that.

This pairs plans with frames by equal stamps. The other pairing, of a frame with its odometry (stamp in
(t - period, t]), is `quad_il.frame_pairing`, the one Python home of that rule.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.types import ImitationError, Observation


def stamp_key(stamp_s: float) -> int:
    """Integer nanoseconds: ROS times are integral nanoseconds, so equal stamps have equal keys."""
    return int(round(stamp_s * 1e9))


@dataclasses.dataclass
class _Slot:
    obs: Observation | None = None
    actions: dict[str, SplineAction | None] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class PairedFrame:
    obs: Observation
    actions: dict[str, SplineAction | None]  # one entry per source; None = no plan for this frame


@dataclasses.dataclass
class PairerStats:
    paired: int = 0
    completed_with_missing: int = 0
    evicted: int = 0
    duplicates: int = 0


class StampPairer:
    def __init__(self, sources: Iterable[str], max_pending: int = 64) -> None:
        self.sources = tuple(sources)
        if not self.sources or len(set(self.sources)) != len(self.sources):
            raise ImitationError(f"sources must be unique and non-empty, got {self.sources}")
        if max_pending < 1:
            raise ImitationError(f"max_pending must be >= 1, got {max_pending}")
        self.max_pending = int(max_pending)
        self._slots: dict[int, _Slot] = {}
        self.stats = PairerStats()

    def add_observation(self, obs: Observation) -> list[PairedFrame]:
        slot = self._slot(stamp_key(obs.stamp_s))
        if slot.obs is not None:
            self.stats.duplicates += 1
        slot.obs = obs
        return self._collect(stamp_key(obs.stamp_s))

    def add_action(self, source: str, stamp_s: float, action: SplineAction | None) -> list[PairedFrame]:
        if source not in self.sources:
            raise ImitationError(f"unknown source {source!r}; expected one of {self.sources}")
        key = stamp_key(stamp_s)
        slot = self._slot(key)
        if source in slot.actions:
            self.stats.duplicates += 1
        slot.actions[source] = action
        return self._collect(key)

    def flush_before(self, stamp_s: float) -> list[PairedFrame]:
        """Complete (with None plans) every slot older than stamp_s that has its observation; drop the
        rest."""
        limit = stamp_key(stamp_s)
        out: list[PairedFrame] = []
        for key in sorted(k for k in self._slots if k < limit):
            slot = self._slots.pop(key)
            if slot.obs is None:
                self.stats.evicted += 1
                continue
            actions = {s: slot.actions.get(s) for s in self.sources}
            self.stats.completed_with_missing += 1
            out.append(PairedFrame(slot.obs, actions))
        return out

    def flush_all(self) -> list[PairedFrame]:
        """Complete every held frame that has its observation (with None for missing plans); drop the rest."""
        if not self._slots:
            return []
        return self.flush_before((max(self._slots) + 1) * 1e-9)

    def waiting_for(self, source: str, stamp_s: float) -> bool:
        """Whether the frame at stamp_s is held with its observation but without `source`'s plan (the rospy
        collector completes it with None once the source has acknowledged the frame without a plan)."""
        slot = self._slots.get(stamp_key(stamp_s))
        return slot is not None and slot.obs is not None and source not in slot.actions

    @property
    def pending(self) -> int:
        return len(self._slots)

    def _slot(self, key: int) -> _Slot:
        if key not in self._slots:
            while len(self._slots) >= self.max_pending:
                del self._slots[min(self._slots)]
                self.stats.evicted += 1
            self._slots[key] = _Slot()
        return self._slots[key]

    def _collect(self, key: int) -> list[PairedFrame]:
        slot = self._slots.get(key)
        if slot is None or slot.obs is None or any(s not in slot.actions for s in self.sources):
            return []
        del self._slots[key]
        self.stats.paired += 1
        # Older incomplete frames can no longer complete (lockstep order): release them first.
        out = self.flush_before(slot.obs.stamp_s)
        out.append(PairedFrame(slot.obs, dict(slot.actions)))
        return out

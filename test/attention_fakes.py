"""A scripted world and memory for driving the attention core without the simulator."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roger_common.types import (
    FEATURE_DIM,
    WEIGHT_INDEX,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    Roi,
    RunCounters,
)


@dataclass
class Obj:
    position: tuple[float, float, float]
    value: float
    weight: float
    activation: float


class FakeWorld:
    """Objects that perception sees perfectly; a haptic goal measures the weight."""

    def __init__(self, objects: dict[str, Obj]) -> None:
        self.objects = dict(objects)

    def rois(self, haptic_target: tuple[float, float, float] | None = None) -> list[Roi]:
        out = []
        for k, o in enumerate(self.objects.values()):
            features = np.full(FEATURE_DIM, o.value, np.float32)
            known = np.ones(FEATURE_DIM, bool)
            touched = haptic_target is not None and math.dist(haptic_target, o.position) < 0.05
            if touched:
                features[WEIGHT_INDEX] = o.weight
            else:
                features[WEIGHT_INDEX], known[WEIGHT_INDEX] = 0.0, False
            out.append(Roi(roi_id=k, bbox=(10 * k, 0, 10 * k + 8, 8), position=o.position,
                           features=features, known=known, activation=o.activation,
                           size_m=0.06))
        return out

    @staticmethod
    def visible(position: tuple[float, float, float]) -> bool:
        return True   # the whole scene is always in view


class FakeMemory:
    """Identifies a stored object when the known features agree; needs the weight unless
    the match is final."""

    def __init__(self, always_new: bool = False) -> None:
        self.stored: list[tuple[np.ndarray, np.ndarray]] = []
        self.requests: list[MemoryRequest] = []
        self.always_new = always_new

    def handle(self, req: MemoryRequest) -> MatchResult:
        self.requests.append(req)
        if req.op is MemoryOp.STORE:
            self.stored.append((req.features.copy(), req.known.copy()))
            return MatchResult(MatchOutcome.NEW, len(self.stored) - 1, 1.0)
        if self.always_new:
            return MatchResult(MatchOutcome.NEW)
        if req.known[WEIGHT_INDEX] or req.final_trial:
            for address, (f, k) in enumerate(self.stored):
                both = k & req.known
                if np.all(np.abs(f[both] - req.features[both]) < 0.02):
                    return MatchResult(MatchOutcome.IDENTIFIED, address, 0.9)
        if req.final_trial:
            return MatchResult(MatchOutcome.NEW)
        return MatchResult(MatchOutcome.UNDETERMINED)


def three_objects() -> dict[str, Obj]:
    return {"a": Obj((0.5, -0.3, 0.05), 0.2, 0.1, 0.4),
            "b": Obj((0.5, 0.0, 0.05), 0.4, 0.5, 0.9),
            "c": Obj((0.5, 0.3, 0.05), 0.6, 0.9, 0.6)}


def check_table2(c: RunCounters) -> None:
    assert c.attention_shifts + c.improvements + c.map_updates == c.cycles
    assert c.map_updates == c.positive_identifications + c.new_objects + c.remaps

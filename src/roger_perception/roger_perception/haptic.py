"""Haptic readings kept by position, so that later frames of the same object carry W.

A haptic improvement happens once per object, but the weight feature must stay known in
every later frame that shows the object. A reading belongs to the object the hand touched:
the ROI of the frame nearest the contact point on the ground plane, within half the ROI's
size plus ``radius`` (the hand may touch a large object anywhere on its top, far from the
centre of its visible surface). The reading is stored at that ROI's position, so that
later ROIs of the object, whose positions jitter by a few centimetres, find it within
``radius``; with no ROI near, at the contact point. A new reading within ``radius`` of an
old one replaces its weight (the object was re-weighed) and adds its touches to the
object's last ``TOUCH_READINGS`` (``shape.touch_shape`` pools them). Distances are taken
on the ground plane (x, y): objects stand on the ground, never on one another.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from roger_common.types import HapticReading, TactileContact
from roger_perception.shape import touch_shape

#: Readings whose touches are pooled per object (the last ones), as the fovea keeps the
#: last 5 outlines of an object (``fovea.FoveaLooks``).
TOUCH_READINGS: int = 5


class HapticMemory:
    """Weights measured by the arms, indexed by contact position.

    Args:
        radius: Distance (metres) within which a reading belongs to a position.
    """

    def __init__(self, radius: float) -> None:
        self.radius = float(radius)
        self._positions: list[np.ndarray] = []
        self._weights: list[float] = []
        self._touch: list[list[tuple[TactileContact, ...]]] = []
        # touch_shape of each entry's readings, computed when they change (every frame
        # asks for it; the tactile images make it cost a millisecond).
        self._shape: list[tuple[float, float, float, float] | None] = []

    def __len__(self) -> int:
        return len(self._weights)

    def add(self, reading: HapticReading, positions: Sequence[Sequence[float]] = (),
            sizes: Sequence[float] = ()) -> bool:
        """Store a reading at the touched object's position (``positions`` and ``sizes``:
        the ROIs of the reading's frame, module docstring); returns False (and stores
        nothing) without a valid contact."""
        if not reading.contact or not math.isfinite(reading.weight) or reading.weight < 0:
            return False
        pos = np.asarray(reading.position, float)
        if not np.all(np.isfinite(pos)):
            return False
        if len(positions):
            rois = np.asarray(positions, float)
            d = np.linalg.norm(rois[:, :2] - pos[:2], axis=1)
            reach = 0.5 * np.asarray(sizes, float) + self.radius
            inside = np.flatnonzero(d <= reach)
            if inside.size:
                pos = rois[inside[np.argmin(d[inside])]]
        touches = [tuple(reading.contacts)] if reading.contacts else []
        i = self._nearest(pos)
        if i is not None:
            self._positions[i] = pos
            self._weights[i] = float(reading.weight)
            self._touch[i] = (self._touch[i] + touches)[-TOUCH_READINGS:]
            self._shape[i] = touch_shape(self._touch[i])
        else:
            self._positions.append(pos)
            self._weights.append(float(reading.weight))
            self._touch.append(touches)
            self._shape.append(touch_shape(touches))
        return True

    def weight_near(self, position: Sequence[float]) -> float | None:
        """Weight (kg) of the nearest reading within the radius, or None."""
        i = self._nearest(np.asarray(position, float))
        return None if i is None else self._weights[i]

    def touch_near(self, position: Sequence[float]) -> tuple[float, ...] | None:
        """TH, TK, TC, TR (``shape.touch_shape``; TR NaN where unknown) of the touches of
        the last readings at the nearest position within the radius; None without one, or
        when none of its readings reported touches."""
        i = self._nearest(np.asarray(position, float))
        return None if i is None else self._shape[i]

    def readings_near(self, position: Sequence[float]) -> list[tuple[TactileContact, ...]]:
        """The touches of the last readings at the nearest position within the radius
        (``shape.creased_albedo`` reads the touched faces' normals); [] without one."""
        i = self._nearest(np.asarray(position, float))
        return [] if i is None else list(self._touch[i])

    def clear(self) -> None:
        """Forget every reading."""
        self._positions.clear()
        self._weights.clear()
        self._touch.clear()
        self._shape.clear()

    def _nearest(self, pos: np.ndarray) -> int | None:
        return nearest_within(self._positions, pos, self.radius)


def nearest_within(positions: Sequence[np.ndarray], pos: np.ndarray, radius: float
                   ) -> int | None:
    """Index of the position nearest ``pos`` on the ground plane, if within ``radius``."""
    if not positions:
        return None
    d = np.linalg.norm(np.stack(positions)[:, :2] - pos[:2], axis=1)
    i = int(np.argmin(d))
    return i if d[i] <= radius else None


def touches(reading: HapticReading | None, position: Sequence[float], radius: float) -> bool:
    """True when ``reading`` is a contact within ``radius`` of ``position`` (ground plane)."""
    if reading is None or not reading.contact:
        return False
    d = np.linalg.norm(np.asarray(reading.position, float)[:2] - np.asarray(position, float)[:2])
    return bool(d <= radius)

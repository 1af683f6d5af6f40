"""Messages <-> roger_perception's inputs of its own. The stereo pair, the haptic reading and
the ROI array are shared types and convert in roger_common.conversions."""

from __future__ import annotations

import math

from roger_common.conversions import point_tuple
from roger_interfaces.msg import SpatialMap


def mapped_positions(msg: SpatialMap) -> list[tuple[float, float, float]]:
    """Positions of the mapped entries of a spatial map (entries with NaN are skipped)."""
    return [p for p in (point_tuple(e.position) for e in msg.entries if e.mapped)
            if all(math.isfinite(v) for v in p)]

"""Messages <-> roger_perception's inputs and outputs of its own. The stereo pair, the haptic
reading and the ROI array are shared types and convert in roger_common.conversions."""

from __future__ import annotations

import math

from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import ImageMarker

from roger_common.conversions import point_tuple
from roger_interfaces.msg import SpatialMap
from roger_perception.overlay import RetinaOverlay

#: Width of the ROI outlines drawn over the retinas, pixels.
OUTLINE_WIDTH_PX = 1.0


def mapped_positions(msg: SpatialMap) -> list[tuple[float, float, float]]:
    """Positions of the mapped entries of a spatial map (entries with NaN are skipped)."""
    return [p for p in (point_tuple(e.position) for e in msg.entries if e.mapped)
            if all(math.isfinite(v) for v in p)]


def overlay_to_msg(overlay: RetinaOverlay, header: Header) -> ImageMarker:
    """One retina's ROI outlines as an ImageMarker LINE_LIST, one colour a segment, with the
    header of the retina's image: Foxglove's Image panel pairs them by stamp."""
    return ImageMarker(
        header=Header(stamp=header.stamp, frame_id=header.frame_id), ns="rois", id=0,
        type=ImageMarker.LINE_LIST, action=ImageMarker.ADD, scale=OUTLINE_WIDTH_PX,
        points=[Point(x=float(u), y=float(v)) for u, v in overlay.points],
        outline_colors=[ColorRGBA(r=float(r), g=float(g), b=float(b), a=float(a))
                        for r, g, b, a in overlay.colors])

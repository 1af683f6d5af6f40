"""Messages <-> roger_bringup core types (the view)."""

from __future__ import annotations

import numpy as np
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from roger_common.conversions import point_tuple
from roger_interfaces.msg import SpatialMap


def view_to_msg(view: np.ndarray, header: Header, frame_id: str = "roger_view") -> Image:
    """An RGB uint8 view as an rgb8 sensor_msgs/Image with the given stamp."""
    data = np.ascontiguousarray(view, dtype=np.uint8)
    h, w, _ = data.shape
    return Image(header=Header(stamp=header.stamp, frame_id=frame_id), height=h, width=w,
                 encoding="rgb8", is_bigendian=0, step=3 * w, data=data.tobytes())


def map_interests(msg: SpatialMap) -> list[tuple[tuple[float, float, float], float]]:
    """(position, interest) of every entry of a spatial map."""
    return [(point_tuple(e.position), float(e.interest)) for e in msg.entries]

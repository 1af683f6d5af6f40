"""Shape evidence beyond equations 1-5: the extended features (docs/perception.md,
"Extended features").

Equations 1-5 measure a silhouette's contrast, texture, stereo relief and area in the image;
a prism seen end-on and side-on gives other values, and a sphere and a cylinder of one grey
and weight give nearly the same. The extended mode adds measurements in the ground frame,
from what the robot knows of its own geometry (camera model and eye pose) and from touch:

Vision (every look; from the left retina's silhouette, the ROI's stereo position and the
known eye pose, never the simulator's objects):

* ``H``: height of the object's top. The ray through the silhouette's topmost pixel, in the
  column of the object's centre, passes over the vertical axis through the object's
  position (x, y) at a height ``z_over``: the top's height plus the part of the top that
  lies behind the axis, seen under the ray's declination. For a body that turns about the
  vertical (sphere, cylinder) nothing of it depends on yaw; for a box it grows by at most
  ``(sqrt 2 - 1) size / 2 tan(declination)`` between yaw 0 and 45 degrees.

Three more visual measurements were built, measured and dropped (docs/perception.md,
"Extended features"): the silhouette's metric height over width (R), how far it reaches
above the top (E) and the median shading gradient (G). Between categories that differ only
in shape they moved as much as between copies of one category at other yaws (ratios 0.7-2.5
on the shape_twins and yaw_copies worlds 1001-1002), and in closed loop they stored prism
copies again.

Touch (after a haptic improvement, like W; from the tactile sensor's contact points and
normals of the first touch and its probe touches, ``HapticReading.contacts``):

* ``TH``: height of the highest contact point: the top's height, felt.
* ``TS``: the steepest slope touched: the largest angle between a contact's surface normal
  and the vertical, over 90 degrees. A box's or a cylinder's top is flat (0); a sphere's
  dome tilts by asin(offset / radius) where the probes land (20-35 degrees for a 10 cm
  sphere); a prism's flanks are 60 degrees steep wherever they are touched, and of three
  probe directions 120 degrees apart one always crosses the ridge, whatever the yaw. The
  drops of the probe contacts below the first were tried first: on a prism they depend
  on where the first touch landed beside the ridge (between copies they differed by 20
  category scales), so they are not used.

Each value is normalised to [0, 1] (clipped) by the constants below, like equations 4-5.
Pure numpy; no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from roger_common.geometry import camera_ray, project_point
from roger_common.types import CameraModel, EyePose, TactileContact

#: Heights are divided by this (metres): a 0.22 m box seen from 35-60 degrees above reads
#: z_over up to about 0.45 m (its far rim), so nothing saturates.
H_MAX_M: float = 0.5


def _ray(camera: CameraModel, pose: EyePose, u: float, v: float) -> np.ndarray:
    return np.asarray(camera_ray(camera, pose, u, v), float)


def height_over_axis(camera: CameraModel, pose: EyePose, u: float, v: float,
                     axis_xy: Sequence[float] | np.ndarray) -> float:
    """Height at which the ray through pixel (u, v) passes over a vertical axis at
    ``axis_xy`` (its point nearest that axis on the ground plane), metres."""
    o = np.asarray(pose.position, float)
    d = _ray(camera, pose, u, v)
    dh = d[:2]
    den = float(np.dot(dh, dh))
    if den <= 1e-12:
        return math.nan
    t = float(np.dot(np.asarray(axis_xy, float)[:2] - o[:2], dh) / den)
    return float(o[2] + t * d[2])


def top_height(mask: np.ndarray, bbox: tuple[int, int, int, int], camera: CameraModel,
               pose: EyePose, position: Sequence[float]) -> float:
    """``z_over`` of one ROI, metres, before normalisation (module docstring); NaN where
    not measurable.

    Args:
        mask: The ROI's silhouette inside ``bbox`` (left retina).
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        camera: The left retina's model.
        pose: The left eye's pose.
        position: The ROI's stereo position, robot frame (z up from the ground).
    """
    vs, us = np.nonzero(mask)
    if vs.size == 0:
        return math.nan
    us = us + bbox[0]
    vs = vs + bbox[1]
    p = np.asarray(position, float)
    # The topmost pixel of the columns within 1.5 px of the centre's column: its top edge
    # (v) is where the silhouette ends.
    cu = project_point(camera, pose, tuple(p))[0]
    near = np.abs(us + 0.5 - cu) <= 1.5
    if not near.any():
        near = np.ones_like(us, bool)
    top = float(vs[near].min())
    cols = np.unique(us[near])
    return float(np.median([height_over_axis(camera, pose, c + 0.5, top, p[:2])
                            for c in cols]))


def visual_features(z_over: float) -> tuple[float]:
    """H normalised to [0, 1] (NaN stays NaN: unknown)."""
    return (_unit(z_over / H_MAX_M),)


def tactile_shape(contacts: Sequence[TactileContact]) -> tuple[float, float] | None:
    """TH and TS from one haptic improvement's touches, normalised to [0, 1].

    Args:
        contacts: The touches, first one first (``HapticReading.contacts``).

    Returns:
        (TH, TS), or None without a touch.
    """
    if not contacts:
        return None
    top = max(c.point[2] for c in contacts)
    steepest = max(math.acos(max(-1.0, min(1.0, c.normal[2] / max(math.hypot(*c.normal),
                                                                   1e-12))))
                   for c in contacts)
    return _unit(top / H_MAX_M), _unit(steepest / (math.pi / 2.0))


def _unit(x: float) -> float:
    if not math.isfinite(x):
        return math.nan
    return float(min(1.0, max(0.0, x)))

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
* ``R``: the silhouette's metric height over its metric width, both at the object's depth:
  a sphere's outline is a disc (1 from any view); a cylinder's, its side plus its top seen
  from above (cos + sin of the declination over 1: 1.3-1.4 at Roger's 35-60 degrees). It
  depends on the view's declination, which changes with distance, but not on the yaw of a
  body of revolution.
* ``E``: ``z_over`` over the silhouette's metric height: how much of the silhouette lies
  above the top (a sphere's outline reaches above its top's projection, a cylinder's ends
  at its rim).
* ``G``: shading. The median intensity gradient (per pixel, after a 0.7 px Gaussian) over
  the ROI's interior (its mask eroded by one pixel), over the ROI's mean intensity. Under
  the world's one directional light a planar face is evenly lit: a box's or a prism's
  interior is flat but for the edges between faces; a sphere's and a cylinder's side shade
  smoothly across. Dividing by the intensity leaves the object's grey out; the face's
  orientation to the light, and so the yaw, still enter.

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

import cv2
import numpy as np

from roger_common.geometry import camera_ray, project_point
from roger_common.types import CameraModel, EyePose, TactileContact

#: Heights are divided by this (metres): a 0.22 m box seen from 35-60 degrees above reads
#: z_over up to about 0.45 m (its far rim), so nothing saturates.
H_MAX_M: float = 0.5
#: R and E are divided by this: their largest value on a world's shapes is below 2.
RATIO_MAX: float = 2.0
#: G is divided by this: the relative gradient of a curved surface of Roger's worlds stays
#: below 0.15 per pixel.
G_MAX: float = 0.2


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


def visual_shape(mask: np.ndarray, bbox: tuple[int, int, int, int], camera: CameraModel,
                 pose: EyePose, position: Sequence[float]) -> tuple[float, float, float]:
    """H, R and E of one ROI in metres and ratios, before normalisation (module docstring).

    Args:
        mask: The ROI's silhouette inside ``bbox`` (left retina).
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        camera: The left retina's model.
        pose: The left eye's pose.
        position: The ROI's stereo position, robot frame (z up from the ground).

    Returns:
        (z_over in metres, height / width, z_over / height); NaN where not measurable.
    """
    vs, us = np.nonzero(mask)
    if vs.size == 0:
        return math.nan, math.nan, math.nan
    us = us + bbox[0]
    vs = vs + bbox[1]
    p = np.asarray(position, float)
    depth = float(np.dot(p - np.asarray(pose.position, float), np.asarray(pose.rotation)[:, 2]))
    if not math.isfinite(depth) or depth <= 0:
        return math.nan, math.nan, math.nan
    metres_per_px = depth / camera.focal_px
    width_m = float(us.max() - us.min() + 1) * metres_per_px
    height_m = float(vs.max() - vs.min() + 1) * metres_per_px
    # The topmost pixel of the columns within 1.5 px of the centre's column: its top edge
    # (v) is where the silhouette ends.
    cu = project_point(camera, pose, tuple(p))[0]
    near = np.abs(us + 0.5 - cu) <= 1.5
    if not near.any():
        near = np.ones_like(us, bool)
    top = float(vs[near].min())
    cols = np.unique(us[near])
    z_over = float(np.median([height_over_axis(camera, pose, c + 0.5, top, p[:2])
                              for c in cols]))
    return z_over, height_m / width_m, z_over / height_m


def shading(image: np.ndarray, mask: np.ndarray, bbox: tuple[int, int, int, int]) -> float:
    """G before normalisation: the median gradient over the ROI's interior over its mean
    intensity (module docstring); NaN for a ROI with no interior or no light.

    Args:
        image: The left retina, float in [0, 1].
        mask: The ROI's silhouette inside ``bbox``.
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
    """
    h, w = image.shape
    pad = 3
    u0, v0, u1, v1 = bbox
    a0, b0 = max(0, u0 - pad), max(0, v0 - pad)
    a1, b1 = min(w, u1 + pad), min(h, v1 + pad)
    win = cv2.GaussianBlur(np.ascontiguousarray(image[b0:b1, a0:a1], np.float32), (0, 0), 0.7)
    gx = cv2.Sobel(win, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(win, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    full = np.zeros(win.shape, np.uint8)
    full[v0 - b0:v1 - b0, u0 - a0:u1 - a0] = mask
    inner = cv2.erode(full, np.ones((3, 3), np.uint8)) > 0
    if inner.sum() < 5:
        return math.nan
    mean = float(win[full > 0].mean())
    if mean <= 1e-3:
        return math.nan
    return float(np.median(np.hypot(gx, gy)[inner])) / mean


def visual_features(z_over: float, ratio: float, reach: float, grad: float
                    ) -> tuple[float, float, float, float]:
    """H, R, E, G normalised to [0, 1] (NaN stays NaN: unknown)."""
    return (_unit(z_over / H_MAX_M), _unit(ratio / RATIO_MAX), _unit(reach / RATIO_MAX),
            _unit(grad / G_MAX))


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

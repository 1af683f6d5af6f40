"""An object in line behind the fixated one, parted from it by the two foveae's disparity.

Where an object stands in line behind a nearer one, within a few degrees of bearing and
5-30 cm farther, the left retina shows its top above the nearer one's, and at 128 px the two
lie 1.5-2 px apart in disparity: the plane sweep's step, so neither the sweep nor the cap
test (``behind.py``) can part them. The far object joins the nearer one's ROI: it never
gets a place of its own in the map, and the nearer one's outline, top height, grey and size
are read off both (docs/perception.md, "Limits"). At the fovea's resolution (3.2 times the
retina's) the same pairs lie 4-7 px apart, while the fixated object's own surface spans
-1..+3 px (``bench/fovea_stereo.py``).

After a visual improvement the simulator renders both eyes' foveae (``SimConfig.fovea_stereo``).
For the ROI the eyes fixate (``fovea.fixated``):

1. **Disparities.** The ROI's silhouette is mapped into the fovea. Where the smoothed left
   fovea changes along the rows (the aperture problem: only there does a horizontal
   disparity exist), the 7 x 7 window is matched along the same row of the right fovea
   (sum of absolute differences, ``RANGE`` px either way) and kept where the right fovea's
   own best match points back within 1 px (left-right consistency: occlusions and the
   flat faces' false matches fail it).
2. **The object's own depth bound.** Every shape of a world is convex and about as deep as
   it is wide, so no part of the fixated object lies farther than its centre's depth plus
   half its measured width (as ``behind.py``). Each sample's disparity at that bound comes
   from the known eye poses (a point on its left ray at that depth, projected into the
   right fovea). A sample whose disparity falls short of it by more than ``MARGIN_PX``
   (the matcher's own scatter on one surface, ``fovea_stereo`` quartiles) lies behind.
3. **The layer behind.** The pixels between the samples take the layer they reach without
   crossing an intensity step (a watershed from the samples over the left fovea); its
   pixels behind, mapped back onto the retina (a retina pixel is behind
   where most of its fovea pixels are), opened with a 2 x 2 square and kept as their
   largest connected piece, are the layer behind when it holds at least ``MIN_SAMPLES``
   consistent samples behind, at least ``min_pixels`` retina pixels, and leaves the
   nearer object at least as many.

The layer's pixels are placed in 3-D at the median depth of its samples (triangulated from
the two eye poses, never the simulator's objects). Perception keeps them by position
(``Layers``): in later frames, from any view, a ROI holding a kept layer's projection is
parted there, so the object behind gets a map entry and attention can visit it, and the
nearer one is measured on its own pixels. A later fixation of the same ROI that finds no
layer behind forgets it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from roger_common.types import CameraModel, EyePose
from roger_perception.fovea import silhouette_in_fovea

#: Half-width of the matched windows, fovea pixels (7 x 7).
HALF: int = 3
#: Disparities searched on either side of zero (the vergence point), fovea pixels.
RANGE: int = 16
#: A pixel is matched where the smoothed fovea's horizontal gradient exceeds this.
GRADIENT: float = 0.02
#: A sample lies behind the fixated object when its disparity falls short of the object's
#: far bound by more than this, fovea pixels.
MARGIN_PX: float = 1.5
#: Consistent samples behind a layer needs.
MIN_SAMPLES: int = 20
#: Samples behind triangulated lower than this above the ground are the ground, metres.
MIN_HEIGHT_M: float = 0.02
#: A match counts where every disparity 2 px or more from it costs more than its cost over
#: this (a periodic texture matches at several).
UNIQUENESS: float = 0.8
#: A retina pixel is behind where more than this share of its fovea pixels are.
VOTE: float = 0.5
#: Left-right consistency: the right pixel's own best match points back within this.
CONSISTENCY_PX: int = 1


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


@dataclass(frozen=True)
class Layer:
    """The part of a ROI that stands behind the fixated object.

    Attributes:
        mask: Retina pixels of the layer, within the ROI's bbox (same shape as its mask).
        points: (N, 3) robot-frame points of the layer's fovea pixels at its depth.
        depth: Median left-eye depth of its samples, metres.
        samples: Consistent samples behind.
    """

    mask: np.ndarray
    points: np.ndarray
    depth: float
    samples: int


def row_disparities(left: np.ndarray, right: np.ndarray, rows: slice, cols: slice
                    ) -> np.ndarray:
    """Left-right consistent disparities (right column minus left column) of the left
    fovea's pixels in ``rows`` x ``cols``; NaN where the two eyes' best matches disagree.
    """
    h, w = left.shape
    r0, r1 = max(0, rows.start - HALF), min(h, rows.stop + HALF)
    c0, c1 = max(0, cols.start - RANGE - HALF), min(w, cols.stop + RANGE + HALF)
    ls = cv2.GaussianBlur(np.asarray(left, np.float32), (0, 0), 0.7)[r0:r1, c0:c1]
    rs = cv2.GaussianBlur(np.asarray(right, np.float32), (0, 0), 0.7)[r0:r1, c0:c1]
    hh, ww = ls.shape
    n = 2 * RANGE + 1
    costs = np.empty((n, hh, ww), np.float32)
    back = np.empty((n, hh, ww), np.float32)
    for k, d in enumerate(range(-RANGE, RANGE + 1)):
        # cost of left pixel u against right pixel u + d
        shifted = cv2.warpAffine(rs, np.array([[1, 0, -d], [0, 1, 0]], np.float32), (ww, hh),
                                 flags=cv2.INTER_NEAREST, borderValue=-1.0)
        cost = np.abs(ls - shifted)
        cost[shifted < 0] = 1.0
        costs[k] = cv2.boxFilter(cost, -1, (2 * HALF + 1, 2 * HALF + 1))
        # the same cost seen from right pixel u + d: shift it onto the right's columns
        back[k] = cv2.warpAffine(costs[k], np.array([[1, 0, d], [0, 1, 0]], np.float32),
                                 (ww, hh), flags=cv2.INTER_NEAREST, borderValue=np.inf)
    k_best = np.argmin(costs, axis=0)
    best = k_best - RANGE              # per left pixel
    # Unique: no disparity 2 px or more away matches within UNIQUENESS of the best (a
    # periodic texture matches at several).
    c_best = np.take_along_axis(costs, k_best[None], axis=0)[0]
    ks = np.arange(n)[:, None, None]
    others = np.where(np.abs(ks - k_best[None]) >= 2, costs, np.inf).min(axis=0)
    unique = c_best < UNIQUENESS * others
    best_right = np.argmin(back, axis=0) - RANGE          # per right pixel
    cols_idx = np.arange(ww)[None, :] + best
    inside = (cols_idx >= 0) & (cols_idx < ww)
    back_d = np.take_along_axis(best_right, np.clip(cols_idx, 0, ww - 1), axis=1)
    ok = (inside & unique & (np.abs(back_d - best) <= CONSISTENCY_PX)
          & (best > -RANGE) & (best < RANGE))
    disp = np.where(ok, best.astype(np.float32), np.nan)
    out = disp[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0]
    return np.asarray(out, np.float32)


def _rays(camera: CameraModel, pose: EyePose, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """Robot-frame directions (N, 3) through pixel centres (us, vs), unit depth along the
    optical axis (z = 1 in the camera frame)."""
    d_cam = np.stack([(us + 0.5 - camera.width / 2.0) / camera.focal_px,
                      (vs + 0.5 - camera.height / 2.0) / camera.focal_px,
                      np.ones_like(us, float)], axis=1)
    return d_cam @ pose.rotation.T


def _project_u(camera: CameraModel, pose: EyePose, points: np.ndarray) -> np.ndarray:
    """Image column of each robot-frame point (N, 3) (pixel centres at +0.5 removed)."""
    p = (points - pose.position) @ pose.rotation
    return camera.focal_px * p[:, 0] / p[:, 2] + camera.width / 2.0 - 0.5


def _triangulate(o_a: np.ndarray, d_a: np.ndarray, o_b: np.ndarray, d_b: np.ndarray
                 ) -> np.ndarray:
    """Midpoints of the shortest segments between ray pairs (vectorised
    ``geometry.triangulate``); NaN for parallel rays."""
    w0 = o_a - o_b
    a = np.einsum("ij,ij->i", d_a, d_a)
    b = np.einsum("ij,ij->i", d_a, d_b)
    c = np.einsum("ij,ij->i", d_b, d_b)
    d = np.einsum("ij,ij->i", d_a, w0)
    e = np.einsum("ij,ij->i", d_b, w0)
    den = a * c - b * b
    den = np.where(np.abs(den) < 1e-12, np.nan, den)
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    return (o_a + s[:, None] * d_a + o_b + t[:, None] * d_b) / 2.0


def layer_behind(left_fovea: np.ndarray, right_fovea: np.ndarray, fovea_camera: CameraModel,
                 camera: CameraModel, left_pose: EyePose, right_pose: EyePose,
                 mask: np.ndarray, bbox: tuple[int, int, int, int], depth: float,
                 width_m: float, min_pixels: int) -> Layer | None:
    """The part of a fixated ROI that stands behind it (module docstring), or None.

    Args:
        left_fovea, right_fovea: The two foveae of one visual improvement.
        fovea_camera: Their intrinsics; ``camera`` the retinas'.
        left_pose, right_pose: The eyes' poses (the foveae's).
        mask, bbox: The ROI's silhouette in the left retina.
        depth: The ROI's depth along the left optical axis, metres.
        width_m: Its image width at its depth, metres (its far bound is ``depth + width_m /
            2``: a box turned 45 degrees has its far corner half its image width behind).
        min_pixels: Least retina pixels of the layer and of what it leaves.
    """
    mapped = silhouette_in_fovea(mask, bbox, camera, fovea_camera, margin=HALF + 1)
    if mapped is None or not np.isfinite(depth) or depth <= 0:
        return None
    sil, ui, vi = mapped
    vs_all, us_all = np.nonzero(sil)
    rows = slice(int(vs_all.min()), int(vs_all.max()) + 1)
    cols = slice(int(us_all.min()), int(us_all.max()) + 1)
    smooth = cv2.GaussianBlur(np.asarray(left_fovea, np.float32), (0, 0), 0.7)
    grad = np.abs(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3))[rows, cols]
    disp = row_disparities(left_fovea, right_fovea, rows, cols)
    sub = sil[rows, cols]
    sample = sub & (grad > GRADIENT) & np.isfinite(disp)
    sv, su = np.nonzero(sample)
    if sv.size < MIN_SAMPLES:
        return None
    su_f, sv_f = su + cols.start, sv + rows.start
    d = disp[sv, su]
    # Its far bound, half its width behind: how much farther that is, in disparity, along
    # each sample's own ray.
    rays = _rays(fovea_camera, left_pose, su_f.astype(float), sv_f.astype(float))
    at_centre = left_pose.position + rays * depth
    at_bound = left_pose.position + rays * (depth + 0.5 * max(width_m, 0.0))
    extent = (_project_u(fovea_camera, right_pose, at_bound)
              - _project_u(fovea_camera, right_pose, at_centre))
    # The fixated object's own surface: the disparities, an object's depth wide, that hold
    # the most samples (the plane sweep's depth is a step of several centimetres, the
    # fovea's a fraction of one; a curved face spreads over a few pixels).
    # Its centre's disparity: their median.
    span = int(np.ceil(float(np.median(extent))))
    lo = np.arange(-RANGE, RANGE + 1)
    held = [(int(np.count_nonzero((d >= c) & (d <= c + span))), -int(c)) for c in lo]
    c_best = -int(max(held)[1])
    d_own = float(np.median(d[(d >= c_best) & (d <= c_best + span)]))
    behind = d > d_own + extent + MARGIN_PX
    if int(behind.sum()) < MIN_SAMPLES:
        return None
    # Samples behind on the ground (the ground just beyond the object's top edge, inside
    # its silhouette's last retina pixel) are no object.
    idx = np.flatnonzero(behind)
    pts_b = _triangulate(
        np.broadcast_to(left_pose.position, (idx.size, 3)), rays[idx],
        np.broadcast_to(right_pose.position, (idx.size, 3)),
        _rays(fovea_camera, right_pose, (su_f[idx] + d[idx]).astype(float),
              sv_f[idx].astype(float)))
    ground = np.zeros_like(behind)
    ground[idx] = ~(np.nan_to_num(pts_b[:, 2], nan=-1.0) > MIN_HEIGHT_M)
    behind &= ~ground
    if int(behind.sum()) < MIN_SAMPLES:
        return None
    # The untextured pixels between the samples (a top face, a flank) take the layer they
    # reach without crossing an intensity step: a watershed from the samples over the
    # fovea's own intensity, so that the boundary between the layers falls on the nearer
    # object's occluding edge, not halfway between the samples.
    hh, ww = sub.shape
    grey = np.clip(smooth[rows, cols] * 255.0, 0.0, 255.0).astype(np.uint8)
    markers = np.where(sub, 0, 3).astype(np.int32)
    own = ~behind & ~ground
    markers[sv[own], su[own]] = 1
    markers[sv[behind], su[behind]] = 2
    markers[sv[ground], su[ground]] = 3
    cv2.watershed(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), markers)
    far_f = sub & (markers == 2)
    near_f = sub & (markers == 1)
    # Back onto the retina: a retina pixel is behind (or the fixated object's) where more
    # than VOTE of its fovea pixels are.
    count = np.zeros(mask.shape, np.float32)
    votes = np.zeros(mask.shape, np.float32)
    votes_near = np.zeros(mask.shape, np.float32)
    vv = vi[rows][:, None].repeat(ww, axis=1)
    uu = ui[cols][None, :].repeat(hh, axis=0)
    inside = sub & (vv >= 0) & (vv < mask.shape[0]) & (uu >= 0) & (uu < mask.shape[1])
    at = (vv[inside], uu[inside])
    np.add.at(count, at, 1.0)
    np.add.at(votes, at, far_f[inside].astype(np.float32))
    np.add.at(votes_near, at, near_f[inside].astype(np.float32))
    far = mask & (count > 0) & (votes > VOTE * count)
    far = cv2.morphologyEx(far.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)) > 0
    # A retina pixel on the boundary holds both; the occluding edge is the nearer object's.
    near = (mask & ~far & (count > 0) & (votes_near > VOTE * count)).astype(np.uint8)
    far &= ~(cv2.dilate(near, _CROSS) > 0)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(far.astype(np.uint8), connectivity=4)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    far = lab == k
    if int(far.sum()) < min_pixels or int((mask & ~far).sum()) < min_pixels:
        return None
    # Its samples: those behind whose retina pixel is in the kept piece.
    sv_r, su_r = vi[sv_f], ui[su_f]
    ok_r = (sv_r >= 0) & (sv_r < mask.shape[0]) & (su_r >= 0) & (su_r < mask.shape[1])
    mine = np.zeros(sv.size, bool)
    mine[ok_r] = far[sv_r[ok_r], su_r[ok_r]]
    mine &= behind
    if int(mine.sum()) < MIN_SAMPLES:
        return None
    pts = _triangulate(
        np.broadcast_to(left_pose.position, (int(mine.sum()), 3)), rays[mine],
        np.broadcast_to(right_pose.position, (int(mine.sum()), 3)),
        _rays(fovea_camera, right_pose, (su_f[mine] + d[mine]).astype(float),
              sv_f[mine].astype(float)))
    cam_z = (pts - left_pose.position) @ left_pose.rotation[:, 2]
    cam_z = cam_z[np.isfinite(cam_z)]
    if cam_z.size < MIN_SAMPLES:
        return None
    z_far = float(np.median(cam_z))
    # The layer's fovea pixels placed at its depth.
    far_fovea = np.zeros_like(sub)
    rv, ru = np.nonzero(inside)
    far_fovea[rv, ru] = far[vv[rv, ru], uu[rv, ru]]
    fv, fu = np.nonzero(far_fovea & sub)
    points = left_pose.position + _rays(fovea_camera, left_pose, (fu + cols.start).astype(float),
                                        (fv + rows.start).astype(float)) * z_far
    return Layer(mask=far, points=points.astype(np.float64), depth=z_far,
                 samples=int(mine.sum()))


def project_layer(points: np.ndarray, camera: CameraModel, pose: EyePose,
                  mask: np.ndarray, bbox: tuple[int, int, int, int], min_pixels: int
                  ) -> np.ndarray | None:
    """The retina pixels of a ROI that a kept layer's points fall on (closed with a 3 x 3
    square, and kept as their largest connected piece), or
    None when fewer than ``min_pixels`` of either part remain."""
    p = (points - pose.position) @ pose.rotation
    front = p[:, 2] > 1e-6
    if not front.any():
        return None
    p = p[front]
    u = np.floor(camera.focal_px * p[:, 0] / p[:, 2] + camera.width / 2.0).astype(int) - bbox[0]
    v = np.floor(camera.focal_px * p[:, 1] / p[:, 2] + camera.height / 2.0).astype(int) - bbox[1]
    ok = (u >= 0) & (u < mask.shape[1]) & (v >= 0) & (v < mask.shape[0])
    if not ok.any():
        return None
    hit = np.zeros(mask.shape, np.uint8)
    hit[v[ok], u[ok]] = 1
    far = (cv2.morphologyEx(hit, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) > 0) & mask
    n, lab, stats, _ = cv2.connectedComponentsWithStats(far.astype(np.uint8), connectivity=4)
    if n <= 1:
        return None
    far = lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if int(far.sum()) < min_pixels or int((mask & ~far).sum()) < min_pixels:
        return None
    return far


class Layers:
    """Layers behind, kept by the position of the ROI they were found in (module
    docstring): a later ROI near that position, or holding the layer's projection, is
    parted there.

    Args:
        radius: A kept layer belongs to a later ROI within this distance, metres.
        keep: Most layers kept (the oldest is dropped).
    """

    def __init__(self, radius: float, keep: int = 16) -> None:
        self.radius = float(radius)
        self.keep = int(keep)
        self._near: list[np.ndarray] = []
        self._layers: list[Layer] = []

    def __len__(self) -> int:
        return len(self._layers)

    def put(self, position: Sequence[float], layer: Layer | None) -> None:
        """Keep ``layer`` for the ROI at ``position`` (replacing one kept near it); None
        forgets the one kept near it."""
        pos = np.asarray(position, float)
        i = self._nearest(pos)
        if i is not None:
            del self._near[i]
            del self._layers[i]
        if layer is None:
            return
        self._near.append(pos)
        self._layers.append(layer)
        if len(self._layers) > self.keep:
            del self._near[0]
            del self._layers[0]

    def near(self, position: Sequence[float]) -> list[Layer]:
        """Kept layers whose ROI was within the radius of ``position``."""
        pos = np.asarray(position, float)
        return [layer for p, layer in zip(self._near, self._layers, strict=True)
                if float(np.linalg.norm(p[:2] - pos[:2])) <= self.radius]

    def clear(self) -> None:
        """Forget every layer."""
        self._near.clear()
        self._layers.clear()

    def _nearest(self, pos: np.ndarray) -> int | None:
        best, index = self.radius, None
        for i, p in enumerate(self._near):
            dist = float(np.linalg.norm(p[:2] - pos[:2]))
            if dist <= best:
                best, index = dist, i
        return index

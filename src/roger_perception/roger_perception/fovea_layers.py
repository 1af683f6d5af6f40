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

**The nearest object's far bound.** Step 2 takes the window of disparities that holds the
most samples for the fixated surface. Where a far object behind shows more textured edge
than the nearer one (a box's lit top that renders like the cylinder behind it: one ROI in
both retinas), that window is the far object's, and the nearer one lies within the merged
ROI's footprint, so neither a layer behind nor one in front is found. Then
(``_beyond_nearest``) the samples above the ground are parted in two by disparity (Otsu's
split); where each part holds ``NEAR_SPLIT_SHARE`` of them and the farther part's
``FAR_QUANTILE`` lies beyond the nearer part's front (its ``NEAR_FRONT`` quantile) plus a
whole object's depth (twice the half-width bound of step 2, the depth of a box turned 45
degrees) and ``MARGIN_PX``, the samples beyond that bound are the layer behind (step 3).
A single object's samples never reach beyond its own front plus its depth.

The layer's pixels are placed in 3-D at the median depth of its samples (triangulated from
the two eye poses, never the simulator's objects). Perception keeps them by position
(``Layers``): in later frames, from any view, a ROI holding a kept layer's projection is
parted there, so the object behind gets a map entry and attention can visit it, and the
nearer one is measured on its own pixels. A later fixation of the same ROI that finds no
layer behind forgets it.

The mirror case, a **layer in front** (``fixated_layers``' second result): fixating the far
object of such a pair, the nearer one's edge may join the far one's ROI. Samples nearer
than the fixated surface by more than its near bound (half its width in front) plus
``MARGIN_PX``, above the ground and farther than ``FOOTPRINT`` half widths plus
``FOOTPRINT_MARGIN_M`` from the ROI's centre on the ground plane (a box's front corner, a
prism's near edge are within), form it as above, unopened (an edge may be a sliver).
Those samples sit on the occluding boundary (a window across it takes the nearer edge's
disparity), so they only say that a nearer object joined; perception confirms it by the
nearer object's own ROI beside it and takes its extent from the greys
(``perception.front_extent``).
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
#: A sample in front is another object's where it stands farther than this many half
#: widths of the fixated ROI from its centre on the ground plane (half a square's
#: diagonal: a box's corner turned to the eye)...
FOOTPRINT: float = float(np.sqrt(2.0))
#: ... plus this, metres (the ROI's centre is the plane sweep's, a step of a few cm).
FOOTPRINT_MARGIN_M: float = 0.03
#: Two groups of samples are two objects only when each holds this share of them.
NEAR_SPLIT_SHARE: float = 0.2
#: The near group's front: this quantile of its disparities.
NEAR_FRONT: float = 0.1
#: The far group lies beyond the near one's far bound when this quantile of it does.
FAR_QUANTILE: float = 0.25


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


@dataclass(frozen=True)
class Layer:
    """The part of a ROI that stands behind (or in front of) the fixated object.

    Attributes:
        mask: Retina pixels of the layer, within the ROI's bbox (same shape as its mask).
        points: (N, 3) robot-frame points of the layer's fovea pixels at its depth.
        depth: Median left-eye depth of its samples, metres.
        samples: Consistent samples behind (in front).
        front: The layer stands in front of the fixated object (the nearer object's
            corner that joined its ROI), not behind it.
        own: Retina pixels of the ROI (same shape as ``mask``) the fovea gave the fixated
            object's own surface (most of their fovea pixels took its samples' layer).
    """

    mask: np.ndarray
    points: np.ndarray
    depth: float
    samples: int
    front: bool = False
    own: np.ndarray | None = None


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
    """The part of a fixated ROI that stands behind it (module docstring), or None: the
    first of :func:`fixated_layers`."""
    return fixated_layers(left_fovea, right_fovea, fovea_camera, camera, left_pose,
                          right_pose, mask, bbox, depth, width_m, min_pixels)[0]


def fixated_layers(left_fovea: np.ndarray, right_fovea: np.ndarray,
                   fovea_camera: CameraModel, camera: CameraModel, left_pose: EyePose,
                   right_pose: EyePose, mask: np.ndarray, bbox: tuple[int, int, int, int],
                   depth: float, width_m: float, min_pixels: int,
                   position: Sequence[float] | None = None
                   ) -> tuple[Layer | None, Layer | None]:
    """The parts of a fixated ROI that stand behind it and in front of it (module
    docstring): (behind, in front), each None when there is none.

    Args:
        left_fovea, right_fovea: The two foveae of one visual improvement.
        fovea_camera: Their intrinsics; ``camera`` the retinas'.
        left_pose, right_pose: The eyes' poses (the foveae's).
        mask, bbox: The ROI's silhouette in the left retina.
        depth: The ROI's depth along the left optical axis, metres.
        width_m: Its image width at its depth, metres (its far bound is ``depth + width_m /
            2``: a box turned 45 degrees has its far corner half its image width behind;
            its near bound as far in front).
        min_pixels: Least retina pixels of the layer behind and of what a layer leaves.
        position: The ROI's robot-frame position; without it no layer in front is
            looked for.
    """
    mapped = silhouette_in_fovea(mask, bbox, camera, fovea_camera, margin=HALF + 1)
    if mapped is None or not np.isfinite(depth) or depth <= 0:
        return None, None
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
        return None, None
    su_f, sv_f = su + cols.start, sv + rows.start
    d = disp[sv, su]
    # Its far bound, half its width behind (and its near bound as far in front): how much
    # farther (nearer) that is, in disparity, along each sample's own ray.
    rays = _rays(fovea_camera, left_pose, su_f.astype(float), sv_f.astype(float))
    half = 0.5 * max(width_m, 0.0)
    u_centre = _project_u(fovea_camera, right_pose, left_pose.position + rays * depth)
    extent = _project_u(fovea_camera, right_pose, left_pose.position + rays * (depth + half)) \
        - u_centre
    extent_front = u_centre - _project_u(fovea_camera, right_pose,
                                         left_pose.position + rays * max(depth - half, 1e-3))
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
    front = d < d_own - extent_front - MARGIN_PX
    samples = _Samples(sub, sv, su, su_f, sv_f, d, rays, rows, cols, ui, vi, smooth)
    layer_front = None
    if position is not None and front.any():
        # In front by its disparity, and outside the fixated object's own footprint: a
        # box's front face or a prism's near edge stands nearer than its surface's median
        # too, but within half its diagonal of its centre on the ground plane.
        idx = np.flatnonzero(front)
        pts = _sample_points(samples, idx, fovea_camera, left_pose, right_pose)
        centre = np.asarray(position, float)[:2]
        away = np.hypot(pts[:, 0] - centre[0], pts[:, 1] - centre[1])
        front[idx] = np.nan_to_num(away, nan=0.0) > FOOTPRINT * half + FOOTPRINT_MARGIN_M
        layer_front = _layer(samples, front, True, mask, fovea_camera, left_pose, right_pose,
                             min_pixels)
    layer_behind_ = _layer(samples, behind, False, mask, fovea_camera, left_pose, right_pose,
                           min_pixels)
    if layer_behind_ is None and layer_front is None:
        # The most samples may be the far object's (its surface taken for the fixated
        # one's): the samples beyond the nearest object, when they form a group of their own.
        beyond = _beyond_nearest(samples, extent, fovea_camera, left_pose, right_pose)
        if beyond is not None:
            layer_behind_ = _layer(samples, beyond, False, mask, fovea_camera, left_pose,
                                   right_pose, min_pixels)
    return layer_behind_, layer_front


def _beyond_nearest(s: "_Samples", extent: np.ndarray, fovea_camera: CameraModel,
                    left_pose: EyePose, right_pose: EyePose) -> np.ndarray | None:
    """The samples beyond the nearest object's far bound where the ROI's samples above
    the ground fall apart into two groups by disparity (Otsu's split): the nearer group
    from its front (its NEAR_FRONT quantile), the farther one with at least
    ``NEAR_SPLIT_SHARE`` of them and its FAR_QUANTILE beyond the near group's front plus a
    whole object's depth (twice ``extent``) and ``MARGIN_PX``. None otherwise."""
    pts = _sample_points(s, np.arange(s.d.size), fovea_camera, left_pose, right_pose)
    up = np.nan_to_num(pts[:, 2], nan=-1.0) > MIN_HEIGHT_M
    d = s.d[up]
    if d.size < 2 * MIN_SAMPLES:
        return None
    t = _otsu(d)
    if t is None:
        return None
    near, far = d[d <= t], d[d > t]
    if min(near.size, far.size) < max(MIN_SAMPLES, NEAR_SPLIT_SHARE * d.size):
        return None
    front = float(np.quantile(near, NEAR_FRONT))
    bound = front + 2.0 * float(np.median(extent)) + MARGIN_PX
    if float(np.quantile(far, FAR_QUANTILE)) <= bound:
        return None
    return up & (s.d > bound)


def _otsu(d: np.ndarray) -> float | None:
    """The disparity that parts ``d`` (integers) into the two groups of least spread."""
    values, counts = np.unique(d, return_counts=True)
    if values.size < 2:
        return None
    w0 = np.cumsum(counts)[:-1].astype(float)
    s0 = np.cumsum(counts * values)[:-1].astype(float)
    n, total = float(counts.sum()), float((counts * values).sum())
    w1 = n - w0
    between = w0 * w1 * (s0 / w0 - (total - s0) / w1) ** 2
    return float(values[int(np.argmax(between))])


@dataclass(frozen=True)
class _Samples:
    """The matched samples of a fixated ROI's fovea (``fixated_layers``)."""

    sub: np.ndarray        # its silhouette within the matched rows x cols
    sv: np.ndarray         # sample rows and columns within them
    su: np.ndarray
    su_f: np.ndarray       # and in the fovea
    sv_f: np.ndarray
    d: np.ndarray          # their disparities
    rays: np.ndarray       # their left rays
    rows: slice
    cols: slice
    ui: np.ndarray         # fovea column / row -> retina column / row within the bbox
    vi: np.ndarray
    smooth: np.ndarray     # the smoothed left fovea


def _sample_points(s: _Samples, idx: np.ndarray, fovea_camera: CameraModel,
                   left_pose: EyePose, right_pose: EyePose) -> np.ndarray:
    """Robot-frame points (N, 3) of the samples ``idx``, triangulated from their left rays
    and their matches in the right fovea."""
    return _triangulate(
        np.broadcast_to(left_pose.position, (idx.size, 3)), s.rays[idx],
        np.broadcast_to(right_pose.position, (idx.size, 3)),
        _rays(fovea_camera, right_pose, (s.su_f[idx] + s.d[idx]).astype(float),
              s.sv_f[idx].astype(float)))


def _layer(s: _Samples, side: np.ndarray, front: bool, mask: np.ndarray,
           fovea_camera: CameraModel, left_pose: EyePose, right_pose: EyePose,
           min_pixels: int) -> Layer | None:
    """The layer of the samples ``side`` (behind the fixated object, or in ``front`` of
    it), or None."""
    side = side.copy()
    if int(side.sum()) < MIN_SAMPLES:
        return None
    sv, su, su_f, sv_f = s.sv, s.su, s.su_f, s.sv_f
    # Samples on the ground (behind: the ground just beyond the object's top edge, inside
    # its silhouette's last retina pixel; in front: the ground at its foot) are no object.
    idx = np.flatnonzero(side)
    pts_b = _sample_points(s, idx, fovea_camera, left_pose, right_pose)
    ground = np.zeros_like(side)
    ground[idx] = ~(np.nan_to_num(pts_b[:, 2], nan=-1.0) > MIN_HEIGHT_M)
    side &= ~ground
    if int(side.sum()) < MIN_SAMPLES:
        return None
    # The untextured pixels between the samples (a top face, a flank) take the layer they
    # reach without crossing an intensity step: a watershed from the samples over the
    # fovea's own intensity, so that the boundary between the layers falls on the nearer
    # object's occluding edge, not halfway between the samples.
    sub = s.sub
    hh, ww = sub.shape
    grey = np.clip(s.smooth[s.rows, s.cols] * 255.0, 0.0, 255.0).astype(np.uint8)
    markers = np.where(sub, 0, 3).astype(np.int32)
    own = ~side & ~ground
    markers[sv[own], su[own]] = 1
    markers[sv[side], su[side]] = 2
    markers[sv[ground], su[ground]] = 3
    cv2.watershed(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), markers)
    layer_f = sub & (markers == 2)
    own_f = sub & (markers == 1)
    # Back onto the retina: a retina pixel is the layer's (or the fixated object's) where
    # more than VOTE of its fovea pixels are.
    count = np.zeros(mask.shape, np.float32)
    votes = np.zeros(mask.shape, np.float32)
    votes_own = np.zeros(mask.shape, np.float32)
    vv = s.vi[s.rows][:, None].repeat(ww, axis=1)
    uu = s.ui[s.cols][None, :].repeat(hh, axis=0)
    inside = sub & (vv >= 0) & (vv < mask.shape[0]) & (uu >= 0) & (uu < mask.shape[1])
    at = (vv[inside], uu[inside])
    np.add.at(count, at, 1.0)
    np.add.at(votes, at, layer_f[inside].astype(np.float32))
    np.add.at(votes_own, at, own_f[inside].astype(np.float32))
    layer = mask & (count > 0) & (votes > VOTE * count)
    own_r = mask & (count > 0) & (votes_own > VOTE * count)
    if front:
        # The nearer object's corner in the fixated ROI may be a sliver of a few pixels:
        # kept unopened. A retina pixel on the boundary holds both, and the occluding edge
        # is the nearer object's: the layer's.
        mine_r = own_r & ~layer
        layer |= mask & (cv2.dilate(layer.astype(np.uint8), _CROSS) > 0) & ~mine_r
    else:
        layer = cv2.morphologyEx(layer.astype(np.uint8), cv2.MORPH_OPEN,
                                 np.ones((2, 2), np.uint8)) > 0
        # A retina pixel on the boundary holds both; the occluding edge is the nearer
        # object's.
        near = (mask & ~layer & (count > 0) & (votes_own > VOTE * count)).astype(np.uint8)
        layer &= ~(cv2.dilate(near, _CROSS) > 0)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(layer.astype(np.uint8), connectivity=4)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    layer = lab == k
    if (not front and int(layer.sum()) < min_pixels) or int((mask & ~layer).sum()) < min_pixels:
        return None
    # Its samples: those of its side whose retina pixel is in the kept piece.
    sv_r, su_r = s.vi[sv_f], s.ui[su_f]
    ok_r = (sv_r >= 0) & (sv_r < mask.shape[0]) & (su_r >= 0) & (su_r < mask.shape[1])
    mine = np.zeros(sv.size, bool)
    mine[ok_r] = layer[sv_r[ok_r], su_r[ok_r]]
    mine &= side
    if int(mine.sum()) < MIN_SAMPLES:
        return None
    pts = _sample_points(s, np.flatnonzero(mine), fovea_camera, left_pose, right_pose)
    cam_z = (pts - left_pose.position) @ left_pose.rotation[:, 2]
    cam_z = cam_z[np.isfinite(cam_z)]
    if cam_z.size < MIN_SAMPLES:
        return None
    z_layer = float(np.median(cam_z))
    # The layer's fovea pixels placed at its depth.
    layer_fovea = np.zeros_like(sub)
    rv, ru = np.nonzero(inside)
    layer_fovea[rv, ru] = layer[vv[rv, ru], uu[rv, ru]]
    fv, fu = np.nonzero(layer_fovea & sub)
    points = left_pose.position + _rays(fovea_camera, left_pose,
                                        (fu + s.cols.start).astype(float),
                                        (fv + s.rows.start).astype(float)) * z_layer
    return Layer(mask=layer, points=points.astype(np.float64), depth=z_layer,
                 samples=int(mine.sum()), front=front, own=own_r & ~layer)


def retina_points(camera: CameraModel, pose: EyePose, mask: np.ndarray,
                  bbox: tuple[int, int, int, int], depth: float) -> np.ndarray:
    """(N, 3) robot-frame points of a retina mask's pixel centres (``mask`` within
    ``bbox``) at ``depth`` along the optical axis."""
    vs, us = np.nonzero(mask)
    rays = _rays(camera, pose, (us + bbox[0]).astype(float), (vs + bbox[1]).astype(float))
    return np.asarray(pose.position + rays * depth, np.float64)


def project_layer(points: np.ndarray, camera: CameraModel, pose: EyePose,
                  mask: np.ndarray, bbox: tuple[int, int, int, int], min_pixels: int,
                  min_layer: int | None = None) -> np.ndarray | None:
    """The retina pixels of a ROI that a kept layer's points fall on (closed with a 3 x 3
    square, and kept as their largest connected piece), or None when fewer than
    ``min_layer`` (default ``min_pixels``) of them or fewer than ``min_pixels`` of the
    rest remain."""
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
    least = min_pixels if min_layer is None else min_layer
    if int(far.sum()) < least or int((mask & ~far).sum()) < min_pixels:
        return None
    return far


class Layers:
    """Layers (behind, or in front), kept by the position of the ROI they were found in
    (module docstring): a later ROI near that position, or holding the layer's
    projection, is parted there.

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

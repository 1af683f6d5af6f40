"""ROIs of a stereo frame: fragments, grouped into objects by convexity, positioned.

1. foreground of the left retina, cut into intensity-homogeneous fragments (watershed,
   ``segmentation.fragment_labels``), slivers given to their neighbours
   (``grouping.absorb_slivers``);
2. one plane sweep (``plane_sweep``) costs every foreground pixel and the ground ring
   around it for every depth hypothesis; a fragment that holds two objects of about the
   same grey (a concave notch of ground where their outlines meet) is cut there, the
   cut guided by the two parts' depths (``segmentation.split_at_notches``);
3. touching fragments are one object unless their union holds such a notch
   (``grouping.group_fragments``): every shape is convex, and so is its image;
4. each object's depth is measured over its pixels away from other objects; a depth at
   which the object could not stand on the ground (a copy of it elsewhere in the other
   eye matched better) gives way to the best one at which it could; objects the right
   eye does not see (mean matching cost above ``max_match_cost``) or smaller than
   ``min_roi_pixels`` are dropped;
5. position: the midpoint of the object's leftmost and rightmost points, each placed by
   its own stereo depth (``_between_extremes``: opposite points of a centrally
   symmetric body, whatever its yaw); where a side cannot be measured, the left
   centroid at the object's depth (the centre of the visible surface). When the ROI is
   cut by the left or right edge of the left retina, the centroid is biased towards the
   inside; its horizontal image position is then taken half the object's estimated
   width from its uncut side (width = its height above the ground, because every shape
   of a world file is about as wide as it is high), never closer to the edge than the
   visible centroid. ``SeenObject.cut`` (and ``Roi.cut``) mark ROIs that touch any edge
   of the left retina;
6. an object standing in line behind a taller one shows only above it, and steps 1-3 join
   it to the nearer one: the top of an object's silhouette that the plane sweep places
   farther behind the object's centre than its shape allows becomes an object of its own
   (``behind.cap_behind``; ``PerceptionConfig.behind_split``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from roger_common.geometry import as_point
from roger_common.types import StereoFrame
from roger_perception.behind import along_rows, cap_behind
from roger_perception.binocular import (
    depths_apart,
    group_labels,
    landing,
    split_by_other_eye,
    split_fragments_by_other_eye,
)
from roger_perception.config import PerceptionConfig
from roger_perception.grouping import (
    absorb_slivers,
    adjacency,
    group_fragments,
    near_other_label,
    owner_lut,
)
from roger_perception.plane_sweep import PlaneSweep, SampledCosts, best_depths, region_curves
from roger_perception.segmentation import (
    Blob,
    blob_of,
    foreground_mask,
    fragment_labels,
    label_boxes,
    split_at_notches,
    sure_ground,
)

#: The ground ring that holds an object's outer edges: 2 px (5x5 dilation).
_RING = np.ones((5, 5), np.uint8)


@dataclass
class SeenObject:
    """One object found in the left retina and matched in the right one.

    Attributes:
        blob: Its region in the left retina.
        depth: Depth (m) along the left optical axis, from the plane sweep.
        position: Robot-frame position (see the module docstring), metres.
        centre_px: Left-retina pixel (u, v) that ``position`` projects to.
        right_px: Where ``centre_px`` falls in the right retina.
        width_px: Horizontal extent in the left retina; estimated when cut by the edge.
        cut: True when the region touches an edge of the left retina.
        cost: Its mean matching cost at ``depth``.
    """

    blob: Blob
    depth: float
    position: tuple[float, float, float]
    centre_px: tuple[float, float]
    right_px: tuple[float, float]
    width_px: float
    cut: bool
    cost: float


def find_objects(frame: StereoFrame, cfg: PerceptionConfig) -> tuple[list[SeenObject],
                                                                      np.ndarray]:
    """Segment the left retina into objects and measure their depth and position.

    Returns:
        (objects in left-retina raster order of their first pixel, label image of the
        left retina: 0 ground or dropped, i + 1 for objects[i]).
    """
    fg, bg = foreground_mask(frame.left, cfg)
    frag = absorb_slivers(fragment_labels(frame.left, fg, bg, cfg), cfg.min_roi_pixels)
    if int(frag.max()) == 0:
        return [], np.zeros(frag.shape, np.int32)
    sweep = PlaneSweep(frame, cfg)
    # Costs for every foreground pixel and the ground 2 px around it. Every other pixel (a
    # checkerboard) halves the sweep's work; edges are >= 2 px wide after the smoothing,
    # so none is lost.
    near_fg = cv2.dilate(fg, _RING) > 0
    rows, cols = np.nonzero(near_fg & _checkerboard(fg.shape))
    sampled = SampledCosts(rows, cols, sweep.costs(rows, cols), fg.shape)
    ground = sure_ground(frame.left, fg)
    frag = split_at_notches(frag, frame.left, ground, bg, cfg.notch_px, cfg.min_roi_pixels,
                            sampled, cfg.depth_sigmas)
    n, lab = _sampled_labels(frag, fg, rows, cols)

    # 3. objects: touching fragments join unless their union holds a notch of ground
    owner = group_fragments(frag, ground, adjacency(frag), cfg.min_roi_pixels, cfg.notch_px)
    # 4. depth of every object
    region, curves, depth, cost = _objects(owner, frag, lab, n, rows, cols, sampled, sweep,
                                           cfg)
    # 5. the right retina's view: a fragment, then a group, that falls on two of its
    # groups there
    if cfg.binocular_split:
        right = group_labels(frame.right, cfg)
        land = landing(frag, owner, depth, sweep, right)
        cut, cut_owner = split_fragments_by_other_eye(frag, owner, land, right, frame.left,
                                                      ground, bg, sampled, cfg)
        if len(cut_owner) > len(owner):
            frag, owner = cut, cut_owner
            n, lab = _sampled_labels(frag, fg, rows, cols)
            region, curves, depth, cost = _objects(owner, frag, lab, n, rows, cols, sampled,
                                                   sweep, cfg)
            land = landing(frag, owner, depth, sweep, right)
        if len(set(owner.values())) < len(owner):
            split = split_by_other_eye(
                frag, owner, land, cfg.min_roi_pixels,
                functools.partial(depths_apart, frag, ground, sampled, cfg.depth_sigmas))
            if split != owner:
                owner = split
                region, curves, depth, cost = _objects(owner, frag, lab, n, rows, cols,
                                                       sampled, sweep, cfg)

    width = frame.camera.width
    objects: list[tuple[int, SeenObject]] = []
    boxes = label_boxes(region)
    textured: np.ndarray | None = None
    for g in sorted(set(owner.values())):
        blob = blob_of(region, g, frame.left, bg, boxes[g])
        if blob.area < cfg.min_roi_pixels:
            continue
        if not _stands(blob, float(depth[g]), sweep):
            depth[g], cost[g] = _standing_depth(curves[:, g], blob, sweep)
        if cost[g] > cfg.max_match_cost:
            continue
        seen = _locate(blob, float(depth[g]), float(cost[g]), region, sampled, sweep, cfg)
        if cfg.behind_split and not seen.cut:
            if textured is None:
                textured = along_rows(frame.left, cfg.grad_threshold)
            cap = _cut_cap(seen, region, sampled, sweep, textured, cfg)
            if cap is not None:
                blob = blob_of(region, g, frame.left, bg)
                seen = _locate(blob, float(depth[g]), float(cost[g]), region, sampled, sweep,
                               cfg)
                cap_blob = blob_of(region, cap, frame.left, bg)
                cap_curve, _ = sampled.curve(cap_blob.mask, cap_blob.bbox[1], cap_blob.bbox[0])
                cap_depth, cap_cost, _ = best_depths(cap_curve[:, None], sweep.inverse_depths)
                if cap_cost[0] <= cfg.max_match_cost:
                    objects.append((raster_index(cap_blob, width),
                                    _place(cap_blob, float(cap_depth[0]), float(cap_cost[0]),
                                           sweep, width)))
        objects.append((raster_index(blob, width), seen))
    objects.sort(key=lambda x: x[0])
    out = [o for _, o in objects]
    labels = np.zeros(frag.shape, np.int32)
    for k, o in enumerate(out):
        u0, v0, u1, v1 = o.blob.bbox
        labels[v0:v1, u0:u1][o.blob.mask] = k + 1
    return out, labels


def raster_index(blob: Blob, width: int) -> int:
    """Raster index of a blob's first pixel in a retina ``width`` pixels wide."""
    first = int(np.flatnonzero(blob.mask.ravel())[0])
    return (blob.bbox[1] + first // blob.mask.shape[1]) * width + (
        blob.bbox[0] + first % blob.mask.shape[1])


def _locate(blob: Blob, depth: float, cost: float, region: np.ndarray,
            sampled: SampledCosts, sweep: PlaneSweep, cfg: PerceptionConfig) -> SeenObject:
    """An object placed (step 5 of the module docstring): ``_place``, then, unless cut by
    an edge, halfway to the midpoint of its extremes."""
    seen = _place(blob, depth, cost, sweep, region.shape[1])
    if not seen.cut:
        centre = _between_extremes(blob, region, sampled, sweep, cfg, depth)
        if centre is not None:
            seen.position = as_point(0.5 * (centre + np.asarray(seen.position)))
    return seen


def _cut_cap(seen: SeenObject, region: np.ndarray, sampled: SampledCosts, sweep: PlaneSweep,
             textured: np.ndarray, cfg: PerceptionConfig) -> int | None:
    """Give an object's cap behind (``behind.cap_behind``) a label of its own in ``region``
    (in place); returns that label, or None when the object has no such cap.

    The bound is the object's centre (its position, along the left optical axis) plus half
    its image width at that depth."""
    blob = seen.blob
    centre = sweep.depth_of(np.asarray(seen.position, float))
    bound = centre + 0.5 * seen.width_px * centre / sweep.camera.focal_px
    u0, v0, u1, v1 = blob.bbox
    cap = cap_behind(blob.mask, (v0, u0), bound, sampled, sweep.costs, sweep.inverse_depths,
                     textured,
                     cfg.min_roi_pixels, cfg.min_stereo_samples, cfg.depth_sigmas)
    if cap is None:
        return None
    label = int(region.max()) + 1
    region[v0:v1, u0:u1][cap] = label
    return label


def _sampled_labels(frag: np.ndarray, fg: np.ndarray, rows: np.ndarray, cols: np.ndarray
                    ) -> tuple[int, np.ndarray]:
    """(largest fragment label, fragment of every sampled pixel): a foreground pixel's
    own, a ground pixel's that of a fragment within 2 px."""
    ring = cv2.dilate(frag.astype(np.float32), _RING).astype(np.int32)
    pixel_label = np.where(fg > 0, frag, ring)
    return int(frag.max()), pixel_label[rows, cols]


def _objects(owner: dict[int, int], frag: np.ndarray, lab: np.ndarray, n: int,
             rows: np.ndarray, cols: np.ndarray, sampled: SampledCosts, sweep: PlaneSweep,
             cfg: PerceptionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(object label image, cost curves, depth, cost) of every object: its label is a
    representative fragment; its depth comes from its pixels away from other objects (all
    its pixels when too few are)."""
    lut = owner_lut(owner, n)
    region, region_lab = lut[frag], lut[lab]
    weights = (~near_other_label(region, cfg.occlusion_band_px))[rows, cols].astype(float)
    curves, support = region_curves(sampled.costs, region_lab, weights, n)
    low = support < cfg.min_depth_pixels  # all near others: use every pixel
    low[0] = False  # the ground's curve is not used
    # Only the pixels of those objects: another object's pixels do not change their sums.
    need = low[region_lab]
    if need.any():
        curves_all, _ = region_curves(sampled.costs[:, need], region_lab[need],
                                      np.ones(int(need.sum())), n)
        curves[:, low] = curves_all[:, low]
    depth, cost, _ = best_depths(curves, sweep.inverse_depths)
    return region, curves, depth, cost


@functools.lru_cache(maxsize=4)
def _checkerboard(shape: tuple[int, ...]) -> np.ndarray:
    """Every other pixel of an image of ``shape`` (read-only: it is shared, one per
    retina size)."""
    r, c = np.indices(shape[:2])
    board = (r + c) % 2 == 0
    board.flags.writeable = False
    return board


def _place(blob: Blob, depth: float, cost: float, sweep: PlaneSweep, width: int
           ) -> SeenObject:
    """Position of an object from its blob and depth (step 5 of the module docstring)."""
    u0, v0, u1, v1 = blob.bbox
    cu, cv = blob.centroid
    cut_left, cut_right = u0 <= 0, u1 >= width
    cut = cut_left or cut_right or v0 <= 0 or v1 >= sweep.camera.height
    width_px = float(u1 - u0)
    if cut_left != cut_right:
        # Height above the ground of the top of the region at this depth, in pixels.
        top = sweep.point(cu, v0 + 0.5, depth)
        width_px = max(width_px, max(0.0, float(top[2])) * sweep.camera.focal_px / depth)
        cu = min(cu, u1 - width_px / 2.0) if cut_left else max(cu, u0 + width_px / 2.0)
    position = sweep.point(cu, cv, depth)
    return SeenObject(blob=blob, depth=depth, position=as_point(position),
                      centre_px=(cu, cv), right_px=sweep.right_pixel(cu, cv, depth),
                      width_px=width_px, cut=cut, cost=cost)


def _between_extremes(blob: Blob, region: np.ndarray, sampled: SampledCosts,
                      sweep: PlaneSweep, cfg: PerceptionConfig, depth: float
                      ) -> np.ndarray | None:
    """Centre of an object: the midpoint of its leftmost and rightmost points, each placed
    in space by its own stereo depth; None when either side cannot be measured.

    The points of a centrally symmetric convex body that lie farthest to either side are
    opposite each other through its centre, whatever its yaw: for a cube seen at an angle
    one is a front corner and the other a back corner. Boxes, cylinders and spheres are
    such bodies; a prism's footprint (a rectangle) is. The visible surface's centroid at
    one depth, in contrast, lies in front of the centre by up to half the object's depth
    for a box seen face on, and by nothing for a sphere, whose outline stereo sees at the
    depth of its centre.

    Each side is measured on the outline's pixels within a pixel of its extreme column and
    the ground ring beside them, at the hypotheses within the object's own extent (its
    width, as deep as wide) of the object's ``depth``: a side has few pixels, and a
    similar edge elsewhere in the other eye must not capture it. Another object's pixels
    in a side's ring are left out of its curve; unless the plane sweep puts them two or
    more hypotheses behind the side (``_behind``), that object may hide the side, and it
    is not measured. Nor is a side whose cost curve is too flat or too thin.
    """
    inv = sweep.inverse_depths
    extent = (blob.bbox[2] - blob.bbox[0]) * depth / sweep.camera.focal_px  # width, m
    near, far = 1.0 / max(depth - extent, 1e-3), 1.0 / (depth + extent)
    window = (inv >= far) & (inv <= near)
    u0, v0, u1, v1 = blob.bbox
    mask = blob.mask
    have = mask.any(axis=1)
    rows = np.flatnonzero(have)
    first = np.argmax(mask, axis=1)
    last = mask.shape[1] - 1 - np.argmax(mask[:, ::-1], axis=1)
    h, w = region.shape
    points = []
    for ends, outward in ((first, -1), (last, +1)):
        extreme = ends[rows].min() if outward < 0 else ends[rows].max()
        band = rows[np.abs(ends[rows] - extreme) <= 2]
        side = np.zeros((v1 - v0, u1 - u0 + 6), bool)  # 3 px of margin on both sides
        # Two pixels of the object and three of the ground ring beside its outline.
        reach = np.arange(-3, 2) if outward < 0 else np.arange(-1, 4)
        side[band[:, None], ends[band][:, None] + 3 + reach[None, :]] = True
        x0 = u0 - 3
        xa, xb = max(x0, 0), min(x0 + side.shape[1], w)
        crop = side[:, xa - x0:xb - x0]
        others = region[v0:v1, xa:xb]
        other = crop & (others > 0) & (others != region[v0 + band[0], u0 + ends[band[0]]])
        crop &= ~other
        curve, n = sampled.curve(crop, v0, xa)
        if n < cfg.min_depth_pixels // 2:
            return None
        side_depth, _, rise = _window_minimum(curve, window, inv)
        if rise < cfg.min_depth_rise:
            return None
        if other.any() and not _behind(sampled.curve(other, v0, xa)[0], window, inv,
                                       side_depth):
            return None  # another object beside it, not clearly behind: it may hide it
        u = float(u0 + extreme + (0.0 if outward < 0 else 1.0))
        v = float(v0 + float(band.sum()) / band.size + 0.5)  # band.mean(), without its set-up
        points.append(sweep.point(u, v, side_depth))
    return 0.5 * (points[0] + points[1])


def _behind(curve: np.ndarray, window: np.ndarray, inv: np.ndarray, depth: float) -> bool:
    """Whether the pixels of ``curve`` (another object's, beside a side) lie two or more
    depth hypotheses behind ``depth``: that object cannot hide the side."""
    if not np.isfinite(curve).all():
        return False
    other, _, _ = _window_minimum(curve, window, inv)
    return 1.0 / other <= 1.0 / depth - 2.0 * float(inv[1] - inv[0])


def _window_minimum(curve: np.ndarray, window: np.ndarray, inverse_depths: np.ndarray
                    ) -> tuple[float, float, float]:
    """``_curve_minimum`` over the hypotheses in ``window`` only: no hypothesis outside
    it wins."""
    outside = 2.0 * float(curve.max()) + 1.0
    return _curve_minimum(np.where(window, curve, outside), inverse_depths)


def _stands(blob: Blob, depth: float, sweep: PlaneSweep) -> bool:
    """Whether an object seen at ``depth`` could stand on the ground: the lowest point of
    its region lies no lower than half its width below the ground and no higher than its
    width above it (objects are about as high as wide; a front object may hide the bottom
    of one behind it). A region cut by the bottom of the retina always could."""
    u0, v0, u1, v1 = blob.bbox
    if v1 >= sweep.camera.height:
        return True
    bottom = np.flatnonzero(blob.mask[-1])
    u = u0 + float(bottom.mean()) + 0.5
    z = float(sweep.point(u, float(v1), depth)[2])
    width = (u1 - u0) * depth / sweep.camera.focal_px
    return -0.5 * width <= z <= width


def _standing_depth(curve: np.ndarray, blob: Blob, sweep: PlaneSweep) -> tuple[float, float]:
    """The best-matching depth at which the object could stand on the ground (``_stands``):
    a copy of an object elsewhere in the other eye can match better at a depth that
    would leave it floating. Falls back to the best match when none could."""
    inv = sweep.inverse_depths
    j = curve.shape[0]
    inner = np.flatnonzero((curve[1:-1] <= curve[:-2]) & (curve[1:-1] <= curve[2:])) + 1
    for k in sorted(inner, key=lambda i: curve[i]):
        lo, hi = max(k - 1, 0), min(k + 2, j)
        local = np.full(j, 2.0 * float(curve.max()) + 1.0)
        local[lo:hi] = curve[lo:hi]
        depth, cost, _ = _curve_minimum(local, inv)
        if _stands(blob, depth, sweep):
            return depth, cost
    depth, cost, _ = _curve_minimum(curve, inv)
    return depth, cost


def _curve_minimum(curve: np.ndarray, inverse_depths: np.ndarray) -> tuple[float, float, float]:
    """``plane_sweep.best_depths`` of one curve, without the array overhead: (depth,
    cost, rise) of its minimum, parabola-refined in inverse depth."""
    j = curve.shape[0]
    b = int(np.argmin(curve))
    c0 = float(curve[b])
    offset = 0.0
    if 0 < b < j - 1:
        cm, cp = float(curve[b - 1]), float(curve[b + 1])
        den = cm - 2.0 * c0 + cp
        if den > 1e-12:
            offset = min(max(0.5 * (cm - cp) / den, -0.5), 0.5)
    step = float(inverse_depths[1] - inverse_depths[0])
    rise = min(float(curve[max(b - 2, 0)]), float(curve[min(b + 2, j - 1)])) - c0
    return 1.0 / (float(inverse_depths[b]) + offset * step), c0, rise

"""Regions of interest of one retina (the thin lines of the paper's Figure 2).

The ground is dark, objects are brighter: the foreground is where the (lightly smoothed)
intensity lies ``fg_threshold`` above the background level, a low quantile of the retina,
plus the faint parts that ``dim_foreground`` finds (an object nearly as dark as the
ground).
Objects that touch in the image form one connected foreground region, so the foreground
is cut further into *fragments*: a marker-based watershed (``cv2.watershed``) whose
markers are the flat parts of the foreground (intensity gradient below
``grad_threshold``). A fragment is an intensity-homogeneous patch, a box face, a plain
object, a texture cell, and never straddles an intensity edge, so two touching objects of
different grey (or differently shaded faces) fall into different fragments. Fragments of
one object are joined again by their stereo depth (``grouping``).

Pixel convention (as roger_common.geometry): pixel (row r, column c) has its centre at
u = c + 0.5, v = r + 0.5.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from roger_perception.config import PerceptionConfig
from roger_perception.plane_sweep import COST_SD_PER_MEAN, SampledCosts

_OPEN_KERNEL = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_SQUARE = np.ones((3, 3), np.uint8)
#: Ground markers start this far (5x5 dilation: 2 px) from the foreground.
_GROUND_GAP = np.ones((5, 5), np.uint8)


@dataclass
class Blob:
    """One connected foreground region of a retina.

    Attributes:
        label: Its value in the label image.
        bbox: (u0, v0, u1, v1), pixels, u1/v1 exclusive.
        area: Pixel count.
        centroid: (u, v) weighted by the intensity above the background, pixels.
        mean_intensity: Average retinal intensity over the region, [0, 1].
        mask: Boolean mask of the region inside ``bbox`` (shape (v1 - v0, u1 - u0)).
    """

    label: int
    bbox: tuple[int, int, int, int]
    area: int
    centroid: tuple[float, float]
    mean_intensity: float
    mask: np.ndarray

    @property
    def width_px(self) -> int:
        """Horizontal extent in pixels."""
        return self.bbox[2] - self.bbox[0]


#: Share of the retina below the background level. Not the median: an object fixated from
#: close fills more than half the retina, and the median then made it "background".
BACKGROUND_QUANTILE = 0.1


def background_level(image: np.ndarray) -> float:
    """Intensity of the ground: a low quantile of the retina (the ground is its darkest
    large surface; objects may cover most of it)."""
    flat = np.asarray(image, np.float32).ravel()
    k = int(flat.size * BACKGROUND_QUANTILE)
    return float(np.partition(flat, k)[k])


def foreground_mask(image: np.ndarray, cfg: PerceptionConfig) -> tuple[np.ndarray, float]:
    """Object pixels of one retina.

    Returns:
        (fg, bg): uint8 mask (1 = object) and the background (ground) level.
    """
    img = np.ascontiguousarray(image, np.float32)
    bg = background_level(img)
    smooth = cv2.GaussianBlur(img, (3, 3), 0.8)
    fg = (smooth > bg + cfg.fg_threshold).astype(np.uint8)
    bright = cv2.morphologyEx(fg, cv2.MORPH_OPEN, _OPEN_KERNEL)
    if cfg.dim_sigmas > 0:
        return bright | dim_foreground(img, bright, cfg), bg
    return bright, bg


#: The dim foreground keeps this far (3x3 dilation: 1 px) from the bright one: the edge
#: of a bright object (its anti-aliased rim) is not a dim object.
_DIM_GAP = np.ones((3, 3), np.uint8)


def dim_foreground(image: np.ndarray, fg: np.ndarray, cfg: PerceptionConfig) -> np.ndarray:
    """Objects too dark for ``fg_threshold``: uint8 mask (1 = object) of the parts of the
    retina that stand ``cfg.dim_sigmas`` of the ground's own noise above the ground.

    A very dark object (grey 25 under the scene's light) renders about 0.02 above the
    ground, a third of ``fg_threshold``, and under it in every pixel
    (docs/world-files.md, dark_bright.yaml). Per pixel that is two of the ground's noise;
    a 5x5 median filter (which, unlike a Gaussian, spreads no bright neighbour's light
    into the ground beside it) brings the noise to a quarter. The ground's level and noise
    are measured on this retina, on the filtered pixels 3 px or more from the foreground
    (median and 1.4826 median absolute deviation, as ``sure_ground``). Kept: the filtered
    pixels above level + ``dim_sigmas`` x noise, 1 px or more from ``fg``, after a 3x3
    opening and a 3x3 closing, in connected parts of at least ``cfg.min_roi_pixels``.
    Shadows are darker than the ground, so they are never in it. On a world of ordinary
    greys it is empty.
    """
    img = np.ascontiguousarray(image, np.float32)
    med = cv2.medianBlur(img, 5)
    away = cv2.dilate(fg, np.ones((7, 7), np.uint8)) == 0
    level = med[away] if away.any() else med.ravel()
    level = level[::2]
    median = float(_median(level))
    spread = 1.4826 * float(_median(np.abs(level - median)))
    if spread <= 0:
        return np.zeros_like(fg)
    dim = ((med > median + cfg.dim_sigmas * spread)
           & (cv2.dilate(fg, _DIM_GAP) == 0)).astype(np.uint8)
    dim = cv2.morphologyEx(dim, cv2.MORPH_OPEN, _SQUARE)
    # A closing fills the 1 px seams where a prism's ridge or a shading edge dips under
    # the threshold, so that its flanks touch and group as one object.
    dim = cv2.morphologyEx(dim, cv2.MORPH_CLOSE, _SQUARE) & (cv2.dilate(fg, _DIM_GAP) == 0)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(dim, connectivity=8)
    small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < cfg.min_roi_pixels)
    dim[np.isin(labels, small[small > 0])] = 0
    return dim


def sure_ground(image: np.ndarray, fg: np.ndarray, sigmas: float = 3.0) -> np.ndarray:
    """Pixels that are ground beyond doubt: outside the foreground and no brighter than the
    ground's level plus ``sigmas`` times its pixel noise.

    Both are measured on this retina, on the pixels at least 3 px from the foreground:
    their median and their spread (1.4826 median absolute deviation). The dark half of a
    checker or a face in shadow can fall below ``fg_threshold`` without being ground;
    it is brighter than the ground by more than the noise, and is not counted as ground
    where the image of a convex object is tested for notches.
    """
    img = np.asarray(image, np.float32)
    median, spread = ground_level(img, fg)
    return (fg == 0) & (img <= median + sigmas * spread)


def ground_level(image: np.ndarray, fg: np.ndarray) -> tuple[float, float]:
    """(median, spread) of ``image`` on the ground: the pixels at least 3 px from ``fg``
    (non-zero: foreground), spread as 1.4826 median absolute deviation."""
    away = cv2.dilate(fg.astype(np.uint8), np.ones((7, 7), np.uint8)) == 0
    level = image[away] if away.any() else image.ravel()
    level = level[::4]  # a quarter of the ground pins its median and spread well enough
    median = float(_median(level))
    return median, 1.4826 * float(_median(np.abs(level - median)))


def window_boxes(image: np.ndarray, roi_labels: np.ndarray,
                 boxes: Sequence[tuple[int, int, int, int]], sigmas: float
                 ) -> list[tuple[int, int, int, int]]:
    """The attention window of every ROI: the box of its pixels where an object is seen.

    A ROI's pixels (``roi_labels == k + 1`` inside ``boxes[k]``, its box) include a rim
    of ground and, where two objects nearly touch in the image, the ground seam between
    them: the 3x3 smoothing of the foreground fills it and the watershed gives it to one
    side, so that side's box reaches along its neighbour's edge (a sphere behind a box:
    a box of 11 x 13 px for a sphere of 8 x 8). Its window is the box of its pixels that
    stand ``sigmas`` of the ground's own noise above the ground's median, both measured
    after a 3x3 median filter (which keeps an object as dark as grey 25 above it and
    brings a one-pixel seam down to the ground), on the pixels 3 px or more from any
    ROI. A side of the box on the retina's edge stays there (the ROI is cut: ``Roi.cut``);
    a ROI with no such pixel, and every ROI when ``sigmas`` is 0, keeps its box.
    """
    if sigmas <= 0 or not boxes:
        return list(boxes)
    filtered = cv2.medianBlur(np.asarray(image, np.float32), 3)
    median, spread = ground_level(filtered, roi_labels > 0)
    stands = filtered > median + sigmas * spread
    height, width = roi_labels.shape
    out = []
    for k, (u0, v0, u1, v1) in enumerate(boxes):
        seen = (roi_labels[v0:v1, u0:u1] == k + 1) & stands[v0:v1, u0:u1]
        rows = np.flatnonzero(seen.any(axis=1))
        cols = np.flatnonzero(seen.any(axis=0))
        if rows.size == 0:
            out.append((u0, v0, u1, v1))
            continue
        out.append((u0 if u0 == 0 else u0 + int(cols[0]),
                    v0 if v0 == 0 else v0 + int(rows[0]),
                    u1 if u1 == width else u0 + int(cols[-1]) + 1,
                    v1 if v1 == height else v0 + int(rows[-1]) + 1))
    return out


def _median(values: np.ndarray) -> np.floating:
    """``np.median`` of a 1-D array without NaN, by the same partition and mean, without
    its NaN check and set-up (most of its cost on a few thousand pixels)."""
    n = values.size
    k = n // 2
    if n % 2:
        return np.partition(values, k)[k]
    return np.mean(np.partition(values, [k - 1, k])[k - 1:k + 1])


def fragment_labels(image: np.ndarray, fg: np.ndarray, bg: float, cfg: PerceptionConfig
                    ) -> np.ndarray:
    """Cut the foreground into intensity-homogeneous fragments (marker-based watershed).

    Markers are the connected parts of the eroded foreground whose gradient magnitude
    (Sobel of the image smoothed with sigma 1 px, per pixel) is below
    ``cfg.grad_threshold``, plus the ground away from the foreground. The watershed floods
    the smoothed image from them; its dividing lines go to a neighbouring fragment, and
    foreground the ground's flood reached becomes fragments by connectivity.

    Returns:
        int32 labels, 0 on the ground, 1..n on fragments (some numbers may be unused).
    """
    img = np.ascontiguousarray(image, np.float32)
    smooth = cv2.GaussianBlur(img, (0, 0), 1.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    # The 3x3 Sobel is 8x the per-pixel gradient.
    flat = ((fg > 0) & (np.hypot(gx, gy) < 8.0 * cfg.grad_threshold)).astype(np.uint8)
    _, seeds = cv2.connectedComponents(cv2.erode(flat, _SQUARE), connectivity=4)
    markers = np.where(seeds > 0, seeds + 1, 0).astype(np.int32)
    markers[cv2.dilate(fg, _GROUND_GAP) == 0] = 1
    grey = _grey(smooth, bg)
    cv2.watershed(cv2.merge([grey, grey, grey]), markers)
    lines = markers < 0
    markers[lines | (markers == 1)] = 0
    markers[lines] = _closest_neighbour(markers, smooth, lines)
    markers[fg == 0] = 0
    markers[markers > 0] -= 1
    # Foreground without a flat seed (busy texture, thin parts) is flooded by the ground:
    # its connected parts become fragments of their own.
    orphans = ((fg > 0) & (markers == 0)).astype(np.uint8)
    if orphans.any():
        _, extra = cv2.connectedComponents(orphans, connectivity=8)
        markers = np.where(extra > 0, extra + int(markers.max()), markers).astype(np.int32)
    return markers


#: Fewest pixels of a notch: a dent of one or two pixels is no T-junction.
_MIN_NOTCH_PIXELS = 3


#: Offsets of the eight neighbours of a pixel (``_closest_neighbour``), as (8, 1) columns.
_NEIGHBOUR_ROWS = np.array([[-1], [-1], [-1], [0], [0], [1], [1], [1]])
_NEIGHBOUR_COLS = np.array([[-1], [0], [1], [-1], [1], [-1], [0], [1]])


def _closest_neighbour(labels: np.ndarray, smooth: np.ndarray, where: np.ndarray
                       ) -> np.ndarray:
    """For the pixels ``where``, the label of the 8-neighbour (labelled > 0) whose
    intensity is closest to theirs; 0 when none is labelled."""
    rows, cols = np.nonzero(where)
    h, w = labels.shape
    # All eight neighbours at once; argmin takes the first of equally close ones, in the
    # order below (row offset, then column offset).
    r = np.clip(rows[None] + _NEIGHBOUR_ROWS, 0, h - 1)
    c = np.clip(cols[None] + _NEIGHBOUR_COLS, 0, w - 1)
    lab = labels[r, c]
    diff = np.abs(smooth[r, c] - smooth[rows, cols][None])
    diff[lab <= 0] = np.inf
    pick = np.argmin(diff, axis=0)
    take = np.arange(rows.size)
    best = np.where(lab[pick, take] > 0, lab[pick, take], 0).astype(np.int32)
    return best


def ground_notches(mask: np.ndarray, ground: np.ndarray, parts: tuple[np.ndarray, ...] = (),
                   deeper_than: float = 0.0) -> list[tuple[float, tuple[int, int]]]:
    """Concave notches of ground in a region: where its convex hull holds ground.

    Every shape of a world is convex, and so is its image up to digitisation (notches of
    about a pixel); a deeper notch of ground is where two objects' outlines meet
    (a T-junction: one partly hides the other).

    Args:
        mask: The region (bool).
        ground: Where the retina shows ground (bool, same shape).
        parts: When given, only notches that touch every one of these masks (same shape)
            count: the corner where two parts' outlines meet.
        deeper_than: Only notches deeper than this (pixels) are wanted.

    Returns:
        (depth, (row, col)) of each connected notch, deepest first: the largest distance
        (pixels) from the hull's edge of a ground pixel inside the hull, and that pixel.
    """
    # Thin appendages (a sliver of a neighbour left to a region, a rim bump) are no part
    # of an outline: the hull is taken of the region opened by a 3 x 3 square.
    contours, _ = cv2.findContours(
        cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, _SQUARE), cv2.RETR_EXTERNAL,
        cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return []
    corners = cv2.convexHull(np.vstack(contours))
    x, y, w, h = cv2.boundingRect(corners)
    sub = mask[y:y + h, x:x + w]
    hull = np.zeros((h + 2, w + 2), np.uint8)
    cv2.fillConvexPoly(hull, corners - np.array([x - 1, y - 1], np.int32), 1)
    notch = (hull[1:-1, 1:-1] > 0) & ~sub & ground[y:y + h, x:x + w]
    if not notch.any():
        return []
    # 3 x 3 chamfer distance: 0.955 per step, 1.37 per diagonal step (a fifth of the
    # exact transform's cost; the thresholds used lie between its values).
    inside = cv2.distanceTransform(hull, cv2.DIST_L2, 3)[1:-1, 1:-1]
    if float(inside[notch].max()) <= deeper_than:
        return []
    n, comp = cv2.connectedComponents(notch.astype(np.uint8), connectivity=8)
    near = [cv2.dilate(p[y:y + h, x:x + w].astype(np.uint8), _SQUARE) > 0 for p in parts]
    out = []
    for k in range(1, n):
        this = comp == k
        # A notch opens onto the hull's edge and is wider than a pixel-sized dent (an
        # enclosed hole or a crack of one or two pixels is a rendering or threshold flaw).
        if this.sum() < _MIN_NOTCH_PIXELS or not (this & (inside <= 1.0)).any():
            continue
        if not all((this & nb).any() for nb in near):
            continue
        depth = np.where(this, inside, -1.0)
        r, c = np.unravel_index(int(np.argmax(depth)), depth.shape)
        if depth[r, c] > deeper_than:
            out.append((float(depth[r, c]), (int(r) + y, int(c) + x)))
    return sorted(out, reverse=True)


def split_at_notches(labels: np.ndarray, image: np.ndarray, ground: np.ndarray, bg: float,
                     notch_px: float, min_pixels: int, costs: SampledCosts | None = None,
                     sigmas: float = 3.0) -> np.ndarray:
    """Cut fragments that hold two objects of about the same grey (no intensity edge
    stopped the watershed between them).

    Such a fragment is not convex: where the outlines of the two objects meet (a
    T-junction) it holds a notch of ground deeper than ``notch_px``. It is cut along the
    straight line that leaves the two most convex parts (least hull area not covered),
    among the lines through its deepest notch (every 15 degrees, and through its second
    deepest notch); the cut is kept when it lowers that uncovered area and leaves two
    parts of ``min_pixels``. A two-marker watershed (the parts of the fragment farther
    than a quarter of the cut's length from the line) then places the cut on the faint
    edge between the two objects where there is one. Parts are cut again while they hold
    a deep notch. On a large fragment a notch must also reach a tenth of the fragment's
    size (the square root of its area): a flaw of the outline (a sliver of the next face
    left to it) stays a pixel or two deep, while the corner between two objects grows
    with them.

    The edge between two objects of about the same grey can be too faint for the
    watershed (a shaded sphere before a box). When ``costs`` are given and the two
    markers (with the ground ring next to them: their outer edges) lie at depths two or
    more hypotheses apart, every undecided pixel whose 5 x 5 window matches one marker's
    depth better than the other's, by more than ``sigmas`` standard errors of the
    difference (the markers' own matching noise), joins that marker first.

    Args:
        labels: Fragment labels (0 ground); not modified.
        image: The retina, [0, 1].
        ground: Where the retina shows ground.
        bg: Ground level of the retina.
        notch_px: Deepest notch a convex shape's image may hold.
        min_pixels: Fragments below twice this are left alone; both parts of a cut must
            hold this many pixels.
        costs: The plane sweep's costs of the sampled pixels, for the depth of the parts.
        sigmas: Margin of a depth preference, in standard errors.

    Returns:
        The new labels (new fragments numbered after the largest label).
    """
    out = labels.copy()
    grey: np.ndarray | None = None  # the watershed's image, made for the first cut
    boxes = label_boxes(out)
    height, width = out.shape
    sizes = np.bincount(out.ravel())
    todo = [i for i in sorted(boxes) if sizes[i] >= 2 * min_pixels]
    next_label = int(out.max()) + 1
    while todo:
        i = todo.pop()
        by0, bx0, by1, bx1 = boxes[i]
        y0, y1 = max(by0 - 1, 0), min(by1 + 1, height)
        x0, x1 = max(bx0 - 1, 0), min(bx1 + 1, width)
        mask = out[y0:y1, x0:x1] == i
        area = int(mask.sum())
        if area < 2 * min_pixels:
            continue
        least = max(float(notch_px), _NOTCH_PER_SIZE * float(np.sqrt(area)))
        if deepest_defect(mask) < least - DEFECT_MARGIN:
            continue  # no concavity of the outline comes near: skip the full test
        notches = ground_notches(mask, ground[y0:y1, x0:x1], deeper_than=least)
        if not notches:
            continue
        cut = _best_cut(mask, [nt[1] for nt in notches[:2]], min_pixels)
        if cut is None:
            continue
        side, length = cut
        keep = max(1.0, 0.25 * length)
        markers = np.where(mask, 0, 3).astype(np.int32)
        markers[mask & (side > keep)] = 1
        markers[mask & (side < -keep)] = 2
        if costs is not None:
            seed_by_depth(markers, mask, ground[y0:y1, x0:x1], costs, (y0, x0), sigmas)
        if grey is None:
            grey = watershed_grey(image, bg)
        part = watershed_part(grey[y0:y1, x0:x1], markers, mask, min_pixels)
        if part is None:
            continue
        crop = out[y0:y1, x0:x1]
        crop[part] = next_label
        crop[mask & (markers == -1)] = i  # watershed lines stay with the first part
        boxes[next_label] = (y0, x0, y1, x1)
        todo += [i, next_label]
        next_label += 1
    return out


def deepest_defect(mask: np.ndarray) -> float:
    """Depth (pixels) of the deepest concavity of the outer contour of ``mask`` (its
    largest part): cheap, and no more than ``DEFECT_MARGIN`` below ``ground_notches``,
    which is only worth running where this comes near the depth wanted.

    ``ground_notches`` takes the hull of every part that survives an opening by a 3 x 3
    square: when two parts do (two fragments that touch only through a stray pixel), the
    ground between them lies in that hull and no outline of one part bounds it, so the
    answer is infinite (take the full test)."""
    # Corners only: the deepest point of a concavity is one of them.
    binary = mask.astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return 0.0
    if len(contours) > 1:
        opened, _ = cv2.findContours(cv2.morphologyEx(binary, cv2.MORPH_OPEN, _SQUARE),
                                     cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if len(opened) > 1:
            return float("inf")
    contour = max(contours, key=cv2.contourArea)
    if len(contour) < 4:
        return 0.0
    hull = cv2.convexHull(contour, returnPoints=False)
    try:
        defects = cv2.convexityDefects(contour, hull)
    except cv2.error:  # a self-touching contour: no cheap answer, take the full test
        return float("inf")
    return 0.0 if defects is None else float(np.reshape(defects, (-1, 4))[:, 3].max()) / 256.0


def label_boxes(labels: np.ndarray) -> dict[int, tuple[int, int, int, int]]:
    """(y0, x0, y1, x1), exclusive ends, of every label > 0 present."""
    flat = labels.ravel()
    idx = np.flatnonzero(flat)
    if idx.size == 0:
        return {}
    lab = flat[idx]
    # A stable sort of 16-bit keys is a radix sort: linear in the pixels, and the same
    # order as the stable sort of the labels themselves.
    small = int(lab.min()) >= 0 and int(lab.max()) < 1 << 16
    order = np.argsort(lab.astype(np.uint16) if small else lab, kind="stable")
    lab, idx = lab[order], idx[order]
    rows, cols = idx // labels.shape[1], idx % labels.shape[1]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    y0, y1 = np.minimum.reduceat(rows, starts), np.maximum.reduceat(rows, starts) + 1
    x0, x1 = np.minimum.reduceat(cols, starts), np.maximum.reduceat(cols, starts) + 1
    return {int(k): (int(a), int(b), int(c), int(d))
            for k, a, b, c, d in zip(lab[starts].tolist(), y0.tolist(), x0.tolist(),
                                     y1.tolist(), x1.tolist(), strict=True)}


#: How much deeper a ground notch (in 3 x 3 chamfer steps from the hull's edge) may reach
#: than the deepest concavity of the outline's pixel centres. Measured on 3148 regions of
#: the simulator's frames: notches of 0.95 at most below a concavity of 1.25, of 1.37 at
#: most below 1.5; the 1.91 that first exceeds ``notch_px`` only from 1.5 on.
DEFECT_MARGIN = 0.25
#: A notch that cuts a fragment reaches at least this share of its size (sqrt of area).
_NOTCH_PER_SIZE = 0.1
#: Directions (radians) of the candidate cuts through a notch.
_CUT_ANGLES = np.deg2rad(np.arange(0.0, 180.0, 15.0))


def _best_cut(mask: np.ndarray, points: list[tuple[int, int]], min_pixels: int
              ) -> tuple[np.ndarray, float] | None:
    """The straight cut of ``mask`` into its two most convex parts (``split_at_notches``).

    Returns:
        (signed distance of every pixel from the cut line, length of the cut inside the
        mask), or None when no cut lowers the hull area the mask leaves uncovered.
    """
    rr, cc = np.indices(mask.shape)
    (ra, ca) = points[0]
    lines = [(np.cos(t), np.sin(t)) for t in _CUT_ANGLES]
    if len(points) > 1:
        (rb, cb) = points[1]
        norm = float(np.hypot(rb - ra, cb - ca))
        if norm >= 1.0:
            lines.append(((rb - ra) / norm, (cb - ca) / norm))
    best, best_score = None, _uncovered(mask)
    for dr, dc in lines:
        side = dr * (cc - ca) - dc * (rr - ra)
        a, b = mask & (side > 0), mask & (side <= 0)
        if a.sum() < min_pixels or b.sum() < min_pixels:
            continue
        score = _uncovered(a) + _uncovered(b)
        if score < best_score:
            best, best_score = side, score
    if best is None:
        return None
    return best, float((mask & (np.abs(best) <= 0.5)).sum())


def _uncovered(mask: np.ndarray) -> int:
    """Pixels of the convex hull of ``mask`` that ``mask`` leaves uncovered."""
    pts = cv2.findNonZero(mask.astype(np.uint8))
    if pts is None:
        return 0
    hull = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
    return int(hull.sum()) - int(mask.sum())


def watershed_grey(image: np.ndarray, bg: float) -> np.ndarray:
    """The image the cuts' watershed floods: smoothed, above the ground level, 8 bits."""
    return _grey(cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 1.0), bg)


def _grey(smooth: np.ndarray, bg: float) -> np.ndarray:
    """A smoothed retina above the ground level ``bg`` as 8 bits (0.5 above it is 255): the
    image every watershed of this module floods."""
    return np.clip((smooth - bg) * (255.0 / 0.5), 0, 255).astype(np.uint8)


def watershed_part(grey: np.ndarray, markers: np.ndarray, mask: np.ndarray,
                   min_pixels: int) -> np.ndarray | None:
    """Flood ``markers`` (1 and 2 the two seeds, 0 undecided, 3 outside ``mask``) over
    ``grey`` (in place: watershed lines become -1).

    Returns:
        The pixels of ``mask`` that went to seed 2, or None when either part holds fewer
        than ``min_pixels``.
    """
    cv2.watershed(cv2.merge([grey, grey, grey]), markers)
    part = mask & (markers == 2)
    if part.sum() < min_pixels or (mask & (markers == 1)).sum() < min_pixels:
        return None
    return part


def seed_by_depth(markers: np.ndarray, mask: np.ndarray, ground: np.ndarray,
                  costs: SampledCosts, origin: tuple[int, int], sigmas: float) -> bool:
    """When markers 1 and 2 lie at depths two or more hypotheses apart, extend them (in
    place) by the undecided pixels of ``mask`` whose window clearly matches one marker's
    depth, and return True (``split_at_notches``)."""
    y0, x0 = origin
    best, c_min = [], []
    for k in (1, 2):
        own = markers == k
        near_ground = cv2.dilate(own.astype(np.uint8), _GROUND_GAP) > 0
        curve, n = costs.curve(own | (near_ground & ground), y0, x0)
        if n == 0:
            return False
        best.append(int(np.argmin(curve)))
        c_min.append(float(curve.min()))
    if abs(best[0] - best[1]) < 2:
        return False
    h, w = mask.shape
    box = (y0, x0, y0 + h, x0 + w)
    m1, n1 = costs.window_means(best[0], box, 2)
    m2, _ = costs.window_means(best[1], box, 2)
    sd = COST_SD_PER_MEAN * max(c_min) * np.sqrt(2.0) / np.sqrt(np.maximum(n1, 1.0))
    undecided = mask & (markers == 0) & (n1 > 0)
    markers[undecided & (m1 < m2 - sigmas * sd)] = 1
    markers[undecided & (m2 < m1 - sigmas * sd)] = 2
    return True


def blob_of(labels: np.ndarray, label: int, image: np.ndarray, bg: float,
            box: tuple[int, int, int, int] | None = None) -> Blob:
    """The Blob of the pixels of ``labels`` equal to ``label`` (there must be some).

    ``box`` (y0, x0, y1, x1; ``label_boxes``) spares the search of the whole image."""
    if box is None:
        rows, cols = np.nonzero(labels == label)
        box = (int(rows.min()), int(cols.min()), int(rows.max()) + 1, int(cols.max()) + 1)
    y, x, y1, x1 = box
    mask = labels[y:y1, x:x1] == label
    return _blob(label, x, y, mask, np.asarray(image, np.float32)[y:y1, x:x1], bg)


def _blob(label: int, x: int, y: int, mask: np.ndarray, crop: np.ndarray, bg: float) -> Blob:
    # Centroid weighted by the intensity above the ground: sub-pixel and steadier
    # under noise than the mask's own centroid.
    mom = cv2.moments(np.where(mask, np.maximum(crop - bg, 0.0), 0.0))  # np.clip's op
    bh, bw = mask.shape
    if mom["m00"] > 0:
        cu, cv = x + 0.5 + mom["m10"] / mom["m00"], y + 0.5 + mom["m01"] / mom["m00"]
    else:
        cu, cv = x + bw / 2.0, y + bh / 2.0
    return Blob(label=label, bbox=(x, y, x + bw, y + bh), area=int(mask.sum()),
                centroid=(float(cu), float(cv)), mean_intensity=float(crop[mask].mean()),
                mask=mask)


def segment_retina(image: np.ndarray, cfg: PerceptionConfig) -> tuple[np.ndarray, list[Blob]]:
    """Connected foreground regions of one retina (touching objects stay merged).

    Args:
        image: Retinal intensities, (H, W), [0, 1].
        cfg: Gives ``fg_threshold`` and ``min_roi_pixels``.

    Returns:
        (labels, blobs): int32 label image (0 = ground, regions too small included) and
        the regions of at least ``min_roi_pixels`` pixels, in label order.
    """
    img = np.ascontiguousarray(image, np.float32)
    fg, bg = foreground_mask(img, cfg)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    blobs: list[Blob] = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(a) for a in stats[i])
        if area < cfg.min_roi_pixels:
            continue
        mask = labels[y:y + bh, x:x + bw] == i
        blobs.append(_blob(i, x, y, mask, img[y:y + bh, x:x + bw], bg))
    return labels, blobs


def contour_samples(blob: Blob, m: int) -> np.ndarray:
    """M points spread evenly along the outer contour of a ROI (equations 1-3).

    The same M for every ROI, whatever its size: small ROIs repeat contour pixels.

    Returns:
        float array (M, 2) of (u, v) pixel coordinates in the full image.
    """
    padded = np.pad(blob.mask.astype(np.uint8), 1)
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    # Arc length along the closed contour, then M equally spaced stations on it.
    seg = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    total = float(seg.sum())
    if total <= 0:
        idx = np.zeros(m, int)
    else:
        stations = (np.arange(m) + 0.5) * total / m
        idx = np.searchsorted(arc, stations, side="right") - 1
    u0, v0 = blob.bbox[0], blob.bbox[1]
    out = pts[idx] - 1.0 + 0.5  # undo the padding, move to pixel centres
    out[:, 0] += u0
    out[:, 1] += v0
    return out

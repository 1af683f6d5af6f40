"""An object standing behind another, seen only above it: a cap cut off by its depth.

Where a smaller object stands in line behind a taller one, all the left retina shows of
it is a few rows above the nearer object's top. When its grey is close to the face in
front, the watershed puts both in one fragment and the convexity test of the grouping
cannot part them (the cap continues the nearer top's outline; docs/perception.md, "An
object behind, seen above another"). The plane sweep can: the cap matches at a depth the
nearer object cannot reach.

Every shape of a world is convex and about as deep as it is wide, so no part of an object
lies farther behind its centre than half its width seen from the eye (a box's far corner
is half its image width behind the centre at any yaw). A **cap behind** is the part of an
object's silhouette that

1. touches the silhouette's top (it is what shows above the nearer one);
2. is made of pixels whose own 3x3 window of samples where the image changes along the
   rows (condition 3) matches best at a hypothesis beyond
   that bound (the object's centre plus half its image width at that depth) by more than
   one hypothesis step (the sweep's resolution: about 13 cm at 1.5 m, where a 0.25 m
   cylinder's far rim lies at the bound itself), connected, with the flat pixels within
   its convex hull (one candidate for each such part; the largest that passes is the cap);
3. taken together over all its pixels where the image changes along the rows (not only
   the sweep's every other one: a cap holds a few dozen), matches best
   beyond the bound and worse, at every hypothesis within it, than at its best by more
   than ``sigmas`` standard errors of the robot's own matching noise
   (``plane_sweep.COST_SD_PER_MEAN``, as ``segmentation.seed_by_depth``), on at least
   ``min_samples`` such samples. Only they measure a horizontal disparity (the aperture
   problem): a lit top face is a band along the rows that matches about as well at any
   depth, and the small vertical disparity of verged eyes put the minimum of such caps
   a width or more behind their object (344 caps cut without this condition over the
   looks at six worlds, 1 with it; docs/perception.md);
4. holds at most ``MAX_SHARE`` of the object's pixels, and at least ``min_pixels`` above
   its lowest row against the nearer object (a 3x3 window straddles the boundary: the
   row below the cap's lowest decided pixels is dropped as the nearer object's, and the
   lowest row kept may still hold both).

Such a cap is another object's: ``roi_finder`` makes it an object of its own.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from roger_perception.plane_sweep import COST_SD_PER_MEAN, SampledCosts

#: The matching costs (J, N) of N left-retina pixels given as (rows, cols).
CostFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: Largest share of an object's silhouette a cap behind may hold: the rest must be the
#: object itself.
MAX_SHARE = 0.25
#: Half-width of the window of samples a pixel's own depth is read over (3x3).
WINDOW_RADIUS = 1
SLACK = 1.0


def window_best_planes(sampled: SampledCosts, box: tuple[int, int, int, int],
                       use: np.ndarray | None = None, radius: int = WINDOW_RADIUS
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's best hypothesis over its window of samples, all hypotheses at once.

    Args:
        box: (y0, x0, y1, x1) of the pixels wanted, exclusive ends.
        use: Retina mask of the samples that count (None: all).

    Returns:
        (best, counts): the arg-min hypothesis of each pixel's window mean (-1 where the
        window holds no sample) and the window's sample count, each (y1 - y0, x1 - x0).
    """
    sums, cnt = sampled.window_sums(slice(None), box, radius, use)
    best = np.argmin(sums, axis=2)  # equal counts per pixel: the sum's minimum is the mean's
    return np.where(cnt > 0, best, -1), cnt


def along_rows(image: np.ndarray, grad_threshold: float) -> np.ndarray:
    """Pixels whose intensity changes along the rows by at least ``grad_threshold`` per
    pixel (Sobel of the image smoothed with sigma 1 px, as ``segmentation.fragment_labels``
    measures flatness): where a horizontal disparity can be measured."""
    smooth = cv2.GaussianBlur(np.ascontiguousarray(image, np.float32), (0, 0), 1.0)
    # The 3x3 Sobel is 8x the per-pixel gradient.
    return np.abs(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)) >= 8.0 * grad_threshold


def cap_behind(mask: np.ndarray, origin: tuple[int, int], bound_depth: float,
               sampled: SampledCosts, costs: CostFn, inverse_depths: np.ndarray,
               textured: np.ndarray, min_pixels: int, min_samples: int, sigmas: float
               ) -> np.ndarray | None:
    """The cap behind of one object's silhouette (module docstring), or None.

    Args:
        mask: The object's silhouette inside its bounding box.
        origin: (y0, x0) of the box in the retina.
        bound_depth: The farthest depth (m, along the left optical axis) a part of the
            object can have: its centre's plus half its width.
        sampled: The sweep's costs of the sampled pixels (every other one), for each
            pixel's window.
        costs: The sweep's costs of any pixels (``PlaneSweep.costs``): a candidate is
            tested on all its pixels, not every other one.
        inverse_depths: The sweep's hypotheses, 1/m, increasing.
        textured: The retina's ``along_rows`` pixels.

    Returns:
        The cap's mask (same shape as ``mask``), or None when there is none.
    """
    area = int(mask.sum())
    if area * MAX_SHARE < min_pixels or bound_depth <= 0:
        return None
    # Hypotheses behind the bound by more than one step: the sweep's resolution, a
    # tenth of a metre at 1.5 m, where a wide cylinder's far rim lies at the bound itself.
    step = float(inverse_depths[1] - inverse_depths[0]) if inverse_depths.size > 1 else 0.0
    far = inverse_depths < 1.0 / bound_depth - SLACK * step
    if not far.any():
        return None
    h, w = mask.shape
    # Only the top of the silhouette can hold a cap of at most MAX_SHARE of it: rows down
    # to where MAX_SHARE of its pixels lie above.
    rows_to = int(np.searchsorted(np.cumsum(mask.sum(axis=1)), area * MAX_SHARE)) + 1
    top = mask[:rows_to]
    y0, x0 = origin
    best, _ = window_best_planes(sampled, (y0, x0, y0 + rows_to, x0 + w), textured)
    behind = top & (best >= 0) & far[np.maximum(best, 0)]
    if not behind.any():
        return None
    _, comp = cv2.connectedComponents(behind.astype(np.uint8), connectivity=8)
    first_row = np.argmax(top, axis=0)  # the silhouette's top row in each column
    cols = np.flatnonzero(top.any(axis=0))
    at_top = np.unique(comp[first_row[cols], cols])
    at_top = at_top[at_top > 0]
    if at_top.size == 0:
        return None
    # Each such part is one candidate cap, with the flat pixels inside its convex hull
    # (undecided: they tell no horizontal disparity) down to its lowest pixel in their
    # column or the next (not into the nearer object's top below it); the largest that
    # passes is the cap.
    rows_down = np.arange(rows_to)[:, None]
    own = textured[y0:y0 + h, x0:x0 + w]
    caps = []
    for k in at_top:
        ys, xs = np.nonzero(comp == k)
        hull = np.zeros((rows_to, w), np.uint8)
        cv2.fillConvexPoly(hull, cv2.convexHull(np.stack([xs, ys], 1).astype(np.int32)), 1)
        cap = np.zeros((h, w), bool)
        cap[:rows_to] = top & (hull > 0) & (rows_down <= _lowest(comp == k, rows_to))
        # A window reaches a pixel past the boundary: the cap's lowest pixel in a column,
        # where the object goes on below it, is the nearer one's.
        below = np.zeros((h, w), bool)
        below[:-1] = mask[1:] & ~cap[1:]
        cap &= ~below
        size = int(cap.sum())
        # ... and the next row may still hold pixels of both: the cap must be a ROI's
        # size without it.
        below[:-1] = mask[1:] & ~cap[1:]
        if min_pixels <= int((cap & ~below).sum()) and size <= MAX_SHARE * area and _behind(
                costs, cap & own, origin, far, min_samples, sigmas):
            caps.append((size, cap))
    return max(caps, key=lambda c: c[0])[1] if caps else None


def _lowest(part: np.ndarray, rows: int) -> np.ndarray:
    """(1, W): the lowest row of ``part`` in each column or its neighbours (-1 where none
    of the three has a pixel)."""
    low = np.where(part.any(axis=0), rows - 1 - np.argmax(part[::-1], axis=0), -1)
    padded = np.pad(low, 1, constant_values=-1)
    return np.maximum(np.maximum(padded[:-2], padded[1:-1]), padded[2:])[None]


def _behind(costs: CostFn, pixels: np.ndarray, origin: tuple[int, int], far: np.ndarray,
            min_samples: int, sigmas: float) -> bool:
    """Condition 3 of the module docstring over every pixel of the mask ``pixels``."""
    rows, cols = np.nonzero(pixels)
    count = int(rows.size)
    if count < max(min_samples, 1):
        return False
    curve = costs(rows + origin[0], cols + origin[1]).mean(axis=1)
    j_best = int(np.argmin(curve))
    if not far[j_best]:
        return False
    sd = COST_SD_PER_MEAN * float(curve[j_best]) * np.sqrt(2.0) / np.sqrt(count)
    return float(curve[~far].min()) - float(curve[j_best]) > sigmas * sd

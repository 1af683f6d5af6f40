"""Regions of interest of one retina (the thin lines of the paper's Figure 2).

The ground is dark, objects are brighter: the foreground is where the (lightly smoothed)
intensity lies ``fg_threshold`` above the background level, a low quantile of the retina.
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

from dataclasses import dataclass

import cv2
import numpy as np

from roger_perception.config import PerceptionConfig

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
    return cv2.morphologyEx(fg, cv2.MORPH_OPEN, _OPEN_KERNEL), bg


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
    grey = np.clip((smooth - bg) * (255.0 / 0.5), 0, 255).astype(np.uint8)
    cv2.watershed(cv2.merge([grey, grey, grey]), markers)
    lines = markers < 0
    markers[lines | (markers == 1)] = 0
    grown = cv2.dilate(markers.astype(np.float32), _SQUARE).astype(np.int32)
    markers[lines] = grown[lines]
    markers[fg == 0] = 0
    markers[markers > 0] -= 1
    # Foreground without a flat seed (busy texture, thin parts) is flooded by the ground:
    # its connected parts become fragments of their own.
    orphans = ((fg > 0) & (markers == 0)).astype(np.uint8)
    if orphans.any():
        _, extra = cv2.connectedComponents(orphans, connectivity=8)
        markers = np.where(extra > 0, extra + int(markers.max()), markers).astype(np.int32)
    return markers


def blob_of(labels: np.ndarray, label: int, image: np.ndarray, bg: float) -> Blob:
    """The Blob of the pixels of ``labels`` equal to ``label`` (there must be some)."""
    rows, cols = np.nonzero(labels == label)
    y, x = int(rows.min()), int(cols.min())
    y1, x1 = int(rows.max()) + 1, int(cols.max()) + 1
    mask = labels[y:y1, x:x1] == label
    return _blob(label, x, y, mask, np.asarray(image, np.float32)[y:y1, x:x1], bg)


def _blob(label: int, x: int, y: int, mask: np.ndarray, crop: np.ndarray, bg: float) -> Blob:
    # Centroid weighted by the intensity above the ground: sub-pixel and steadier
    # under noise than the mask's own centroid.
    mom = cv2.moments(np.where(mask, np.clip(crop - bg, 0.0, None), 0.0))
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

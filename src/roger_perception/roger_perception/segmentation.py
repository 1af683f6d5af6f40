"""Regions of interest of one retina (the thin lines of the paper's Figure 2).

The ground is dark, objects are brighter: a ROI is a connected region whose (lightly
smoothed) intensity lies ``fg_threshold`` above the background level, the median of the
retina. Objects that touch in the image merge into one ROI.

Pixel convention (as roger_common.geometry): pixel (row r, column c) has its centre at
u = c + 0.5, v = r + 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from roger_perception.config import PerceptionConfig

_OPEN_KERNEL = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


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


def background_level(image: np.ndarray) -> float:
    """Intensity of the ground: the median of the retina (objects cover less than half)."""
    flat = np.asarray(image, np.float32).ravel()
    mid = flat.size // 2
    return float(np.partition(flat, mid)[mid])


def segment_retina(image: np.ndarray, cfg: PerceptionConfig) -> tuple[np.ndarray, list[Blob]]:
    """Split one retina into ROIs.

    Args:
        image: Retinal intensities, (H, W), [0, 1].
        cfg: Gives ``fg_threshold`` and ``min_roi_pixels``.

    Returns:
        (labels, blobs): int32 label image (0 = ground, regions too small included) and
        the regions of at least ``min_roi_pixels`` pixels, in label order.
    """
    img = np.ascontiguousarray(image, np.float32)
    bg = background_level(img)
    smooth = cv2.GaussianBlur(img, (3, 3), 0.8)
    fg = (smooth > bg + cfg.fg_threshold).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, _OPEN_KERNEL)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    blobs: list[Blob] = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(a) for a in stats[i])
        if area < cfg.min_roi_pixels:
            continue
        mask = labels[y:y + bh, x:x + bw] == i
        crop = img[y:y + bh, x:x + bw]
        # Centroid weighted by the intensity above the ground: sub-pixel and steadier
        # under noise than the mask's own centroid.
        mom = cv2.moments(np.where(mask, np.clip(crop - bg, 0.0, None), 0.0))
        if mom["m00"] > 0:
            cu, cv = x + 0.5 + mom["m10"] / mom["m00"], y + 0.5 + mom["m01"] / mom["m00"]
        else:
            cu, cv = x + bw / 2.0, y + bh / 2.0
        blobs.append(Blob(
            label=i,
            bbox=(x, y, x + bw, y + bh),
            area=area,
            centroid=(float(cu), float(cv)),
            mean_intensity=float(crop[mask].mean()),
            mask=mask,
        ))
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

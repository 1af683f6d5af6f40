"""Features of a ROI, equations 1-5 of section 3.1.

Sampling "in the vicinity of the LoG response": the LoG of a flat object interior is ~0
and its response peaks at about sigma on either side of the object's edge. A sample is
therefore taken at each of M points evenly spread along the ROI's outer contour and holds
the largest response magnitude within ``vicinity_sigmas * sigma_k`` pixels of it. By the
linearity of the LoG that value is proportional to the object's contrast against the
dark ground, so I^(k) rises with the object's intensity (Table 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from roger_common.types import FEATURE_DIM, FEATURE_NAMES, WEIGHT_INDEX
from roger_perception.config import PerceptionConfig
from roger_perception.log_filter import kernel_edge_peak, log_kernel


def g_max(cfg: PerceptionConfig) -> tuple[float, float, float]:
    """G_max^(k): peak response of kernel k to a straight edge of contrast ``contrast_max``.

    An object edge of that contrast against the ground gives I^(k) = 1; I^(k) is then
    about (object contrast) / contrast_max, proportional to the object's intensity.
    Small objects at the coarse resolution respond more than an edge (up to
    ``kernel_blob_peak / kernel_edge_peak`` ~ 3 times) and may saturate at 1.
    """
    g1, g2, g3 = (cfg.contrast_max * kernel_edge_peak(log_kernel(s, n))
                  for s, n in zip(cfg.log_sigmas, cfg.kernel_sizes(), strict=True))
    return g1, g2, g3


def vicinity_radius(sigma: float, cfg: PerceptionConfig) -> int:
    """Radius in pixels of the neighbourhood a sample looks into at resolution sigma."""
    return max(1, round(cfg.vicinity_sigmas * sigma))


def vicinity_magnitude(response: np.ndarray, radius: int) -> np.ndarray:
    """Largest |G| within a (2 radius + 1)^2 square around every pixel."""
    k = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(np.abs(response), k)


@dataclass(frozen=True)
class Rim:
    """Where a ROI's outer contour is its own silhouette edge (see :func:`rim_samples`).

    Attributes:
        points: (M, 2) sample points (u, v) on the own edge.
        own_share: Share of the contour that borders the ground.
        on_border: The contour touches the retina's edge (the silhouette is cut).
        neighbours: Labels of the other ROIs the contour touches.
    """

    points: np.ndarray
    own_share: float
    on_border: bool
    neighbours: frozenset[int]


class LabelNeighbours:
    """For every pixel of a label image, the largest and the smallest non-zero label within
    1 px (8-neighbourhood): whether, and which, other ROIs touch a ROI's contour pixel,
    computed once per frame for all ROIs.

    Attributes:
        shape: (H, W) of the label image.
        high: Largest label within 1 px (0 where only ground).
        low: Smallest non-zero label within 1 px (``NONE`` where only ground).
    """

    NONE = np.iinfo(np.int32).max

    def __init__(self, labels: np.ndarray) -> None:
        k = np.ones((3, 3), np.uint8)
        lab = labels.astype(np.float32)  # cv2 morphology has no int32; labels are small
        self.shape = labels.shape
        self.high = cv2.dilate(lab, k).astype(np.int32)
        self.low = cv2.erode(np.where(labels > 0, lab, np.float32(self.NONE)), k)
        self.low = np.where(self.low >= self.NONE, self.NONE, self.low).astype(np.int64)


def rim_samples(mask: np.ndarray, bbox: tuple[int, int, int, int], near: LabelNeighbours,
                own: int, m: int) -> Rim:
    """M points along the part of a ROI's outer contour that is its own silhouette edge.

    The contour of a ROI is the object's edge against the ground only where the ground
    lies outside it: where another ROI touches it (an occlusion, or a neighbour in front)
    or the retina's edge cuts it, the LoG responds to the other object or to nothing, not
    to this object's contrast. Those contour points are left out; the M samples are spread
    evenly (by arc length) over the rest. With no own edge at all, the samples are spread
    over the whole contour.

    Args:
        mask: The ROI's mask inside ``bbox``.
        bbox: (u0, v0, u1, v1) of the mask in the image.
        near: The neighbours of the frame's label image (0 ground, ``own`` this ROI,
            others other ROIs).
        own: This ROI's label.
        m: Number of samples.
    """
    h, w = near.shape
    # A zero frame of one pixel (cheaper than np.pad, whose set-up costs more than a
    # small mask's copy).
    padded = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    contours, _ = cv2.findContours(padded, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = max(contours, key=len).reshape(-1, 2).astype(np.int64) - 1
    pts[:, 0] += bbox[0]
    pts[:, 1] += bbox[1]
    u, v = pts[:, 0], pts[:, 1]
    on_border = (u <= 0) | (v <= 0) | (u >= w - 1) | (v >= h - 1)
    # Another ROI within 1 px (8-neighbourhood) of the contour pixel.
    high, low = near.high[v, u], near.low[v, u]
    above, below = high != own, (low != own) & (low != LabelNeighbours.NONE)
    other = above | below
    neighbours = frozenset(int(x) for x in np.unique(np.concatenate([high[above],
                                                                     low[below]])))
    edge = ~(on_border | other)
    chosen = pts[edge] if edge.any() else pts
    step = np.diff(np.vstack([chosen, chosen[:1]]).astype(float), axis=0)
    seg = np.sqrt(np.add.reduce(step * step, axis=1))  # np.linalg.norm's arithmetic
    # Arc length over the kept points, counting a jump between two kept runs as 1 px.
    seg = np.minimum(seg, 1.5)
    arc = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    total = float(seg.sum())
    idx = np.zeros(m, int) if total <= 0 else \
        np.searchsorted(arc, (np.arange(m) + 0.5) * total / m, side="right") - 1
    return Rim(chosen[idx].astype(np.float64) + 0.5, float(edge.mean()),
               bool(on_border.any()), neighbours)


def own_vicinity(magnitude: np.ndarray, labels: np.ndarray, own: int, bbox: tuple[int, ...],
                 radius: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Largest |G| within a (2 radius + 1)^2 square around every pixel near one ROI,
    other ROIs' pixels left out (their own edges are not this object's contrast).

    Returns:
        (window of the dilated magnitude, (u, v) of its top-left corner in the image).
    """
    h, w = labels.shape
    pad = radius + 1
    u0, v0 = max(0, bbox[0] - pad), max(0, bbox[1] - pad)
    u1, v1 = min(w, bbox[2] + pad), min(h, bbox[3] + pad)
    lab = labels[v0:v1, u0:u1]
    win = np.where((lab != 0) & (lab != own), 0.0, magnitude[v0:v1, u0:u1])
    k = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(win.astype(np.float32), k), (u0, v0)


def sample_at(images: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Values at (u, v) points (nearest pixel, clamped to the image).

    Args:
        images: (H, W) or (K, H, W) array.
        points: (M, 2) pixel coordinates.

    Returns:
        (M,) or (K, M) samples.
    """
    h, w = images.shape[-2:]
    cols = np.clip(np.floor(points[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.floor(points[:, 1]).astype(int), 0, h - 1)
    return images[..., rows, cols]


def intensity_texture(samples: np.ndarray, gmax: float | np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """I^(k) (equation 1) and T^(k) (equation 2) from M samples G_{i+m}^(k).

    Each normalised sample G / G_max is clipped to [0, 1], so I and T lie in [0, 1].

    Args:
        samples: (M,) samples of one resolution, or (K, M) for K resolutions.
        gmax: G_max^(k): a scalar, or (K,) values.

    Returns:
        (I, T), each of shape samples.shape[:-1] (0-d for one resolution).
    """
    g = np.asarray(samples, np.float64)
    g = np.clip(g / np.asarray(gmax, np.float64)[..., None], 0.0, 1.0)
    m = g.shape[-1]
    i_k = g.sum(axis=-1) / m  # eq. 1
    t_k = ((g - i_k[..., None]) ** 2).sum(axis=-1) / m  # eq. 2
    return i_k, t_k


def stereo_feature(measurements: np.ndarray, s_max: float, min_valid: int = 1
                   ) -> tuple[np.ndarray, np.ndarray]:
    """S^(k) (equation 3): variance of the normalised stereo measurements of the samples.

    A sample whose measurement failed is NaN and left out: M and N of equation 3 are the
    number of valid samples (the mean is over the same samples). Normalised measurements
    are clipped to [-1, 1], so S lies in [0, 1].

    Args:
        measurements: (M,) for one resolution, or (K, M); NaN where a match failed.
        s_max: s_max, in the measurements' unit.
        min_valid: Fewer valid samples than this leave S^(k) unknown (0).

    Returns:
        (S, known), each of shape measurements.shape[:-1].
    """
    s = np.clip(np.asarray(measurements, np.float64) / s_max, -1.0, 1.0)
    valid = np.isfinite(s)
    m = valid.sum(axis=-1)
    known = m >= max(1, min_valid)
    sv = np.where(valid, s, 0.0)
    mean_n = sv.sum(axis=-1, keepdims=True) / np.maximum(m, 1)[..., None]  # (1/N) sum s/s_max
    var = (np.where(valid, sv - mean_n, 0.0) ** 2).sum(axis=-1) / np.maximum(m, 1)  # eq. 3
    return np.where(known, var, 0.0), known


def size_feature(d_m: float, d_max_m: float) -> float:
    """D (equation 4): metric size over D_max, clipped to [0, 1]."""
    if not math.isfinite(d_m):
        return 0.0
    return float(min(1.0, max(0.0, d_m / d_max_m)))  # eq. 4


def weight_feature(w_kg: float, w_max_kg: float) -> float:
    """W (equation 5): weight over W_max, clipped to [0, 1]."""
    if not math.isfinite(w_kg):
        return 0.0
    return float(min(1.0, max(0.0, w_kg / w_max_kg)))  # eq. 5


def assemble(intensity: np.ndarray, texture: np.ndarray, stereo: np.ndarray, size: float,
             weight: float | None, stereo_known: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Feature vector in FEATURE_NAMES order and its known mask.

    Args:
        intensity, texture, stereo: I^(k), T^(k), S^(k) for k = 1, 2, 3.
        size: D.
        weight: W, or None when no haptic improvement has measured it yet.
        stereo_known: Which S^(k) were measured (default: all).

    Returns:
        (features float32 (FEATURE_DIM,), known bool (FEATURE_DIM,)); unknown ones hold 0.
    """
    feats = np.zeros(FEATURE_DIM, np.float32)
    for prefix, values in (("I", intensity), ("T", texture), ("S", stereo)):
        for k in range(3):
            feats[FEATURE_NAMES.index(f"{prefix}{k + 1}")] = values[k]
    feats[FEATURE_NAMES.index("D")] = size
    known = np.ones(FEATURE_DIM, bool)
    if stereo_known is not None:
        for k in range(3):
            known[FEATURE_NAMES.index(f"S{k + 1}")] = bool(stereo_known[k])
    if weight is None:
        known[WEIGHT_INDEX] = False
    else:
        feats[WEIGHT_INDEX] = weight
    np.clip(feats, 0.0, 1.0, out=feats)
    return feats, known

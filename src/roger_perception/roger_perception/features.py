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


def stereo_feature(disparities: np.ndarray, s_max: float) -> np.ndarray:
    """S^(k) (equation 3): variance of the normalised disparities of the M samples.

    N of equation 3 equals M here (the mean is over the same samples). Normalised
    disparities are clipped to [-1, 1], so S lies in [0, 1].

    Args:
        disparities: (M,) for one resolution, or (K, M).
        s_max: s_max, pixels.

    Returns:
        S of shape disparities.shape[:-1] (0-d for one resolution).
    """
    s = np.clip(np.asarray(disparities, np.float64) / s_max, -1.0, 1.0)
    m = s.shape[-1]
    mean_n = s.sum(axis=-1, keepdims=True) / m  # (1/N) sum_n s_{i+n} / s_max, N = M
    return ((s - mean_n) ** 2).sum(axis=-1) / m  # eq. 3


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
             weight: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Feature vector in FEATURE_NAMES order and its known mask.

    Args:
        intensity, texture, stereo: I^(k), T^(k), S^(k) for k = 1, 2, 3.
        size: D.
        weight: W, or None when no haptic improvement has measured it yet.

    Returns:
        (features float32 (FEATURE_DIM,), known bool (FEATURE_DIM,)); an unknown W holds 0.
    """
    feats = np.zeros(FEATURE_DIM, np.float32)
    for prefix, values in (("I", intensity), ("T", texture), ("S", stereo)):
        for k in range(3):
            feats[FEATURE_NAMES.index(f"{prefix}{k + 1}")] = values[k]
    feats[FEATURE_NAMES.index("D")] = size
    known = np.ones(FEATURE_DIM, bool)
    if weight is None:
        known[WEIGHT_INDEX] = False
    else:
        feats[WEIGHT_INDEX] = weight
    np.clip(feats, 0.0, 1.0, out=feats)
    return feats, known

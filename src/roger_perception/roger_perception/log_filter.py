"""The visual buffer: a Laplacian of Gaussian at three kernel diameters (section 3).

The kernel is the scale-normalised, sign-flipped LoG ``-sigma^2 * laplacian(G_sigma)``
("Mexican hat"): a bright blob of radius ``sqrt(2) * sigma`` on a dark ground gives the
largest positive response at its centre, a straight edge of contrast c gives a pair of
peaks of about +-0.24 c at +-sigma from it, and a flat region gives 0. Scale
normalisation makes the responses of the three resolutions comparable.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from roger_perception.config import PerceptionConfig, kernel_size


def log_kernel(sigma: float, size: int | None = None) -> np.ndarray:
    """Scale-normalised negative LoG kernel that sums to zero.

    Args:
        sigma: Gaussian sigma in pixels (> 0).
        size: Odd kernel diameter in pixels; default ``2 * ceil(3 sigma) + 1``.

    Returns:
        float32 array (size, size), read-only, symmetric, zero sum.

    Raises:
        ValueError: On a non-positive sigma or an even or too small size.
    """
    if not sigma > 0:
        raise ValueError(f"log_kernel: sigma={sigma!r} must be > 0")
    size = kernel_size(sigma) if size is None else int(size)
    if size < 3 or size % 2 == 0:
        raise ValueError(f"log_kernel: size={size!r} must be odd and >= 3")
    return _cached_kernel(float(sigma), size)


@lru_cache(maxsize=64)
def _cached_kernel(sigma: float, size: int) -> np.ndarray:
    half = size // 2
    x = np.arange(-half, half + 1, dtype=np.float64)
    rho = (x[None, :] ** 2 + x[:, None] ** 2) / (2.0 * sigma * sigma)
    # -sigma^2 * laplacian(G) = (1 - rho) exp(-rho) / (pi sigma^2), rho = r^2 / (2 sigma^2)
    k = (1.0 - rho) * np.exp(-rho) / (np.pi * sigma * sigma)
    k -= k.mean()  # truncation leaves a small DC term; a flat image must give exactly 0
    out = k.astype(np.float32)
    out.flags.writeable = False
    return out


def kernel_blob_peak(kernel: np.ndarray) -> float:
    """Largest response of ``kernel`` to any image with values in [0, 1].

    It is reached by a bright blob that covers exactly the kernel's positive centre
    (radius ``sqrt(2) sigma``): the sum of the positive weights.
    """
    return float(kernel[kernel > 0].sum())


def kernel_edge_peak(kernel: np.ndarray) -> float:
    """Largest response magnitude of ``kernel`` to a straight step edge of contrast 1.

    The response to a step at column offset x is the sum of the kernel's columns on the
    bright side of it, so the peak is the largest partial sum of the column sums.
    """
    cols = np.asarray(kernel, np.float64).sum(axis=0)
    return float(np.abs(np.cumsum(cols)).max())


def log_response(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Filter one retina with one kernel (float32, same shape, replicated border)."""
    return cv2.filter2D(_as_f32(image), cv2.CV_32F, kernel, borderType=cv2.BORDER_REPLICATE)


def log_pyramid(image: np.ndarray, cfg: PerceptionConfig) -> list[np.ndarray]:
    """The visual buffer of one retina: LoG responses at the resolutions k = 1, 2, 3.

    Args:
        image: Retinal intensities, shape (H, W), values in [0, 1].
        cfg: Gives the sigmas and kernel diameters.

    Returns:
        Three float32 arrays of shape (H, W), finest resolution first.
    """
    img = _as_f32(image)
    return [
        log_response(img, log_kernel(s, n))
        for s, n in zip(cfg.log_sigmas, cfg.kernel_sizes(), strict=True)
    ]


def _as_f32(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"retina image must be 2-D, got shape {img.shape}")
    return np.ascontiguousarray(img, dtype=np.float32)

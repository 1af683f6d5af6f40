"""The visual buffer: LoG kernels and the three-resolution pyramid (roger_perception.log_filter).

That the core imports without ROS is checked elsewhere.
"""

from __future__ import annotations

import numpy as np
import pytest

from roger_common.errors import ConfigError
from roger_perception.config import PerceptionConfig
from roger_perception.log_filter import (
    kernel_blob_peak,
    kernel_edge_peak,
    log_kernel,
    log_pyramid,
    log_response,
)


def _disk(size: int, radius: float, contrast: float = 1.0, supersample: int = 8) -> np.ndarray:
    """Anti-aliased bright disk centred in a dark (size x size) image."""
    n = size * supersample
    c = (np.arange(n) + 0.5) / supersample - size / 2.0
    inside = (c[None, :] ** 2 + c[:, None] ** 2) <= radius * radius
    return (contrast * inside.reshape(size, supersample, size, supersample).mean(axis=(1, 3))
            ).astype(np.float32)


@pytest.mark.parametrize("sigma", [0.8, 1.0, 1.5, 2.2, 4.0])
def test_kernel_sums_to_zero_and_is_a_mexican_hat(sigma: float) -> None:
    k = log_kernel(sigma)
    assert k.shape[0] == k.shape[1] and k.shape[0] % 2 == 1
    assert abs(float(k.sum())) < 1e-5 * float(np.abs(k).sum())
    assert np.allclose(k, k.T) and np.allclose(k, k[::-1, ::-1])
    c = k.shape[0] // 2
    assert k[c, c] > 0  # bright centre
    assert k[c, c + round(2 * sigma)] < 0  # dark ring at r = 2 sigma


def test_kernel_size_follows_sigma_and_can_be_given() -> None:
    assert log_kernel(1.0).shape == (7, 7)
    assert log_kernel(2.0).shape == (13, 13)
    assert log_kernel(2.0, 9).shape == (9, 9)
    assert abs(float(log_kernel(2.0, 9).sum())) < 1e-5


@pytest.mark.parametrize("sigma,size", [(0.0, None), (-1.0, None), (1.0, 4), (1.0, 1)])
def test_kernel_rejects_bad_arguments(sigma: float, size: int | None) -> None:
    with pytest.raises(ValueError):
        log_kernel(sigma, size)


@pytest.mark.parametrize("sigmas", [(1.0, 1.5, 2.2), (1.0, 2.0, 4.0)])
def test_each_resolution_responds_most_to_a_blob_of_its_own_scale(sigmas) -> None:
    cfg = PerceptionConfig(log_sigmas=sigmas)
    for k, sigma in enumerate(sigmas):
        img = _disk(64, np.sqrt(2.0) * sigma)
        centre = [float(g[32, 32]) for g in log_pyramid(img, cfg)]
        assert int(np.argmax(centre)) == k, centre
        assert centre[k] > 0.0


def test_blob_of_own_scale_reaches_the_kernel_blob_peak() -> None:
    sigma = 2.0
    k = log_kernel(sigma)
    resp = log_response(_disk(64, np.sqrt(2.0) * sigma), k)
    assert resp[32, 32] == pytest.approx(kernel_blob_peak(k), rel=0.1)
    # Analytic value of the continuous kernel: 2 / e.
    assert kernel_blob_peak(k) == pytest.approx(2.0 / np.e, rel=0.05)


def test_straight_edge_response_peaks_at_the_edge_peak() -> None:
    k = log_kernel(1.5)
    img = np.zeros((40, 40), np.float32)
    img[:, 20:] = 0.3
    resp = log_response(img, k)
    assert float(np.abs(resp[20]).max()) == pytest.approx(0.3 * kernel_edge_peak(k), rel=1e-4)
    # Continuous value: sigma * g_sigma(sigma) = exp(-1/2) / sqrt(2 pi) = 0.242 per unit step.
    assert kernel_edge_peak(k) == pytest.approx(np.exp(-0.5) / np.sqrt(2 * np.pi), rel=0.1)
    assert np.allclose(resp[:, :10], 0.0, atol=1e-6)  # flat ground gives nothing


def test_pyramid_has_three_float32_responses_and_is_linear() -> None:
    cfg = PerceptionConfig()
    rng = np.random.default_rng(3)
    img = rng.random((32, 48)).astype(np.float32) * 0.5
    out = log_pyramid(img, cfg)
    out2 = log_pyramid(2.0 * img, cfg)
    assert len(out) == 3
    for a, b in zip(out, out2, strict=True):
        assert a.shape == img.shape and a.dtype == np.float32
        np.testing.assert_allclose(b, 2.0 * a, atol=1e-5)
    flat = log_pyramid(np.full((20, 20), 0.4, np.float32), cfg)
    assert all(np.abs(g).max() < 1e-5 for g in flat)


def test_pyramid_rejects_a_colour_image() -> None:
    with pytest.raises(ValueError):
        log_pyramid(np.zeros((8, 8, 3), np.float32), PerceptionConfig())


def test_config_kernel_sizes_follow_the_sigmas() -> None:
    cfg = PerceptionConfig(log_sigmas=(1.0, 2.0, 4.0), kernel_radius_sigmas=3.0)
    assert cfg.kernel_sizes() == (7, 13, 25)


@pytest.mark.parametrize("field,value", [
    ("log_sigmas", (2.0, 1.0, 3.0)),
    ("log_sigmas", (1.0, 2.0)),
    ("log_sigmas", (0.0, 1.0, 2.0)),
    ("samples_m", 1),
    ("samples_m", 8.5),
    ("contrast_max", 0.0),
    ("s_max_m", float("nan")),
    ("stereo_search_px", 0),
    ("border_margin_px", -1),
    ("w_max_kg", -2.0),
    ("fg_threshold", 1.5),
    ("min_roi_pixels", 0),
    ("kernel_radius_sigmas", 1.0),
    ("max_area_ratio", 0.5),
    ("weight_motion", -1.0),
    ("cv_threads", 0),
    ("cv_threads", True),
])
def test_config_rejects_bad_values_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        PerceptionConfig(**{field: value})


def test_config_rejects_all_zero_activation_weights() -> None:
    zeros = dict.fromkeys(PerceptionConfig.weight_names(), 0.0)
    with pytest.raises(ConfigError):
        PerceptionConfig(**zeros)


def test_perception_sets_opencv_threads_from_its_config() -> None:
    import cv2

    from roger_perception.perception import Perception
    before = cv2.getNumThreads()
    try:
        Perception(PerceptionConfig(cv_threads=2))
        assert cv2.getNumThreads() == 2
        Perception()  # the default: one thread, no busy-waiting workers
        assert cv2.getNumThreads() == 1
    finally:
        cv2.setNumThreads(before)

"""Depth of image regions by a plane sweep of the left retina against the right one.

Section 3.1 obtains stereo "from the correlation between pairs of pixels, one in ... each
retina". Here the correlation is done for whole fragments and ROIs at once: for each of
J depth hypotheses Z_j (planes parallel to the left retina, evenly spaced in inverse depth
so that one step moves a pixel about ``sweep_step_px`` along its epipolar line), every
left pixel p is mapped into the right retina,

    q_j(p) ~ K (A K^-1 p + t / Z_j),  A = R_right^T R_left,  t = R_right^T (c_left - c_right),

and its cost is the truncated absolute difference of the two (slightly smoothed)
intensities. A region's cost curve is the mean over its pixels; its depth is the arg
min, refined with a parabola in inverse depth. The eyes verge and nothing is rectified:
the mapping uses the frame's own eye poses. Pixels whose match leaves the right retina
cost the truncation value, so a region cannot win by sliding out of the other eye.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from roger_common.types import StereoFrame
from roger_perception.config import PerceptionConfig

#: Smoothing (Gaussian sigma, pixels) of both retinas before the costs: halves pixel noise.
_SMOOTH_SIGMA = 0.7


class PlaneSweep:
    """The depth hypotheses of one stereo frame and the matching costs of left pixels.

    Args:
        frame: The stereo pair and its geometry.
        cfg: Gives ``sweep_near_m``, ``sweep_far_m``, ``sweep_step_px`` and
            ``match_cost_trunc``.
    """

    def __init__(self, frame: StereoFrame, cfg: PerceptionConfig) -> None:
        cam = frame.camera
        self.camera = cam
        self.trunc = float(cfg.match_cost_trunc)
        r_l = np.asarray(frame.left_pose.rotation, float)
        r_r = np.asarray(frame.right_pose.rotation, float)
        c_l = np.asarray(frame.left_pose.position, float)
        c_r = np.asarray(frame.right_pose.position, float)
        self._a = r_r.T @ r_l
        self._t = r_r.T @ (c_l - c_r)
        self._r_l, self._c_l = r_l, c_l
        fb = cam.focal_px * float(np.linalg.norm(self._t))
        span = (1.0 / cfg.sweep_near_m - 1.0 / cfg.sweep_far_m) * fb
        n = max(3, math.ceil(span / cfg.sweep_step_px) + 1)
        #: Inverse depths 1 / Z_j (1/m) of the hypotheses, increasing.
        self.inverse_depths = np.linspace(1.0 / cfg.sweep_far_m, 1.0 / cfg.sweep_near_m, n)
        self._left = cv2.GaussianBlur(np.asarray(frame.left, np.float32), (0, 0), _SMOOTH_SIGMA)
        self._right = cv2.GaussianBlur(np.asarray(frame.right, np.float32), (0, 0),
                                       _SMOOTH_SIGMA)

    def costs(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Matching costs of left pixels for every hypothesis.

        Args:
            rows, cols: (N,) integer pixel indices in the left retina.

        Returns:
            float32 (J, N): min(|L(p) - R(q_j(p))|, match_cost_trunc), the truncation value
            where q_j(p) falls outside the right retina.
        """
        cam = self.camera
        mu, mv, den = self._map(cols + 0.5, rows + 0.5, self.inverse_depths[:, None])
        inside = (mu >= 0) & (mu <= cam.width - 1) & (mv >= 0) & (mv <= cam.height - 1)
        inside &= den > 0
        out = np.empty(mu.shape, np.float32)
        step = 32000  # cv2.remap needs maps narrower than 32767
        for s in range(0, mu.shape[1], step):
            sl = slice(s, s + step)
            out[:, sl] = cv2.remap(self._right, mu[:, sl], mv[:, sl], cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
        np.abs(out - self._left[rows, cols][None], out=out)
        np.minimum(out, self.trunc, out=out)
        out[~inside] = self.trunc
        return out

    def _map(self, u: np.ndarray, v: np.ndarray, rho: np.ndarray | float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Right-retina array coordinates (u - 0.5, v - 0.5) of left pixels at inverse depth
        rho, and the projective depth (must be > 0). float32 throughout: it is the bulk of
        the sweep's arithmetic."""
        cam = self.camera
        f = np.float32(cam.focal_px)
        x = np.stack([(u - cam.width / 2.0) / cam.focal_px,
                      (v - cam.height / 2.0) / cam.focal_px, np.ones_like(u)])
        a = (self._a @ x).astype(np.float32)
        rho = np.asarray(rho, np.float32)
        t = self._t.astype(np.float32)
        den = a[2] + rho * t[2]
        inv = np.float32(1.0) / np.where(np.abs(den) > 1e-6, den, np.float32(1e-6))
        mu = a[0] + rho * t[0]
        mu *= inv
        mu *= f
        mu += np.float32(cam.width / 2.0 - 0.5)
        mv = a[1] + rho * t[1]
        mv *= inv
        mv *= f
        mv += np.float32(cam.height / 2.0 - 0.5)
        return mu, mv, den

    def right_pixels(self, u: np.ndarray, v: np.ndarray, depth: float | np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Right-retina pixels (u, v) of left pixels (u, v) at ``depth`` (one for all, or
        one per pixel), and whether each lies in front of the right eye."""
        mu, mv, den = self._map(np.asarray(u, float), np.asarray(v, float),
                                1.0 / np.asarray(depth, float))
        return mu + np.float32(0.5), mv + np.float32(0.5), den > 0

    def right_pixel(self, u: float, v: float, depth: float) -> tuple[float, float]:
        """Right-retina pixel (u, v) of the left pixel (u, v) at ``depth`` (left optical axis)."""
        mu, mv, _ = self._map(np.array([u]), np.array([v]), 1.0 / depth)
        return float(mu[0]) + 0.5, float(mv[0]) + 0.5

    def depth_of(self, point: np.ndarray) -> float:
        """Depth (m) along the left optical axis of a robot-frame point."""
        return float((self._r_l.T @ (np.asarray(point, float) - self._c_l))[2])

    def point(self, u: float, v: float, depth: float) -> np.ndarray:
        """Robot-frame point seen at left pixel (u, v) at ``depth`` along the optical axis."""
        cam = self.camera
        x = np.array([(u - cam.width / 2.0) / cam.focal_px,
                      (v - cam.height / 2.0) / cam.focal_px, 1.0])
        return self._c_l + self._r_l @ (x * depth)


def region_curves(costs: np.ndarray, labels: np.ndarray, weights: np.ndarray, n: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean cost curve of every label.

    Args:
        costs: (J, N) costs of N pixels.
        labels: (N,) label of each pixel, 0..n.
        weights: (N,) weight of each pixel (0 leaves it out).
        n: Largest label.

    Returns:
        (curves (J, n + 1), support (n + 1,)): the weighted mean cost per hypothesis and
        label, and the summed weight of each label.
    """
    support = np.bincount(labels, weights=weights, minlength=n + 1)
    keep = weights > 0
    order = np.argsort(labels[keep], kind="stable")
    lab = labels[keep][order]
    weighted = costs[:, keep][:, order] * weights[keep][order].astype(np.float32)[None]
    sums = np.zeros((costs.shape[0], n + 1))
    if lab.size:
        starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
        sums[:, lab[starts]] = np.add.reduceat(weighted, starts, axis=1)
    return sums / np.maximum(support, 1e-9)[None], support


def best_depths(curves: np.ndarray, inverse_depths: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth of each curve's minimum, parabola-refined in inverse depth.

    Returns:
        (depth, cost, sharpness) per column: depth (m) along the left optical axis, the
        minimum mean cost, and how much the cost rises two hypotheses away from the
        minimum (the smaller rise of the two sides; small = ambiguous, e.g. a region
        whose only edges run along the epipolar lines).
    """
    j, n = curves.shape
    cols = np.arange(n)
    best = np.argmin(curves, axis=0)
    c0 = curves[best, cols]
    cm = curves[np.maximum(best - 1, 0), cols]
    cp = curves[np.minimum(best + 1, j - 1), cols]
    den = cm - 2.0 * c0 + cp
    inner = (best > 0) & (best < j - 1) & (den > 1e-12)
    offset = np.where(inner, 0.5 * (cm - cp) / np.where(inner, den, 1.0), 0.0)
    step = inverse_depths[1] - inverse_depths[0]
    rho = inverse_depths[best] + np.clip(offset, -0.5, 0.5) * step
    rise = np.minimum(curves[np.maximum(best - 2, 0), cols],
                      curves[np.minimum(best + 2, j - 1), cols]) - c0
    return 1.0 / rho, c0, rise


#: sd of the truncated absolute difference of two equal intensities with Gaussian noise,
#: relative to its mean: sqrt(pi / 2 - 1). It turns a region's mean residual cost at its
#: best depth into the spread of one pixel's cost (the robot's own matching noise).
COST_SD_PER_MEAN = float(np.sqrt(np.pi / 2.0 - 1.0))


@dataclass
class SampledCosts:
    """The matching costs of the sampled left pixels, for regions and small windows.

    Attributes:
        rows, cols: (N,) the sampled pixels.
        costs: (J, N) their costs for every hypothesis (``PlaneSweep.costs``).
        shape: The retina's (H, W).
    """

    rows: np.ndarray
    cols: np.ndarray
    costs: np.ndarray
    shape: tuple[int, int]
    _index: np.ndarray | None = field(default=None, repr=False)

    def index(self) -> np.ndarray:
        """(H, W) index of each pixel's sample, -1 where there is none."""
        if self._index is None:
            self._index = np.full(self.shape, -1, np.int64)
            self._index[self.rows, self.cols] = np.arange(self.rows.size)
        return self._index

    def curve(self, mask: np.ndarray, y0: int = 0, x0: int = 0) -> tuple[np.ndarray, int]:
        """Mean cost curve (J,) over the samples inside ``mask`` (placed at row y0, col
        x0 of the retina) and how many samples that is."""
        h, w = mask.shape
        idx = self.index()[y0:y0 + h, x0:x0 + w][mask]
        idx = idx[idx >= 0]
        if idx.size == 0:
            return np.full(self.costs.shape[0], np.inf), 0
        return self.costs[:, idx].mean(axis=1), int(idx.size)

    def window_means(self, plane: int, box: tuple[int, int, int, int], radius: int
                     ) -> tuple[np.ndarray, np.ndarray]:
        """Mean cost at one hypothesis over the samples of each pixel's square window.

        Args:
            plane: The hypothesis.
            box: (y0, x0, y1, x1) of the pixels wanted, exclusive ends.
            radius: Half-width of the window, pixels.

        Returns:
            (means, counts), each (y1 - y0, x1 - x0); means are 0 where counts are 0.
        """
        sums, cnt = self.window_sums(slice(plane, plane + 1), box, radius)
        return np.where(cnt > 0, sums[:, :, 0] / np.maximum(cnt, 1.0), 0.0), cnt

    def window_sums(self, planes: slice, box: tuple[int, int, int, int], radius: int,
                    use: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Summed costs of the samples in each pixel's square window, for some hypotheses.

        Args:
            planes: The hypotheses (a slice of them).
            box: (y0, x0, y1, x1) of the pixels wanted, exclusive ends.
            radius: Half-width of the window, pixels.
            use: Retina mask of the samples that count (None: all).

        Returns:
            (sums (y1 - y0, x1 - x0, K) for the K hypotheses, counts (y1 - y0, x1 - x0)).
        """
        y0, x0, y1, x1 = box
        h, w = self.shape
        ya, xa = max(y0 - radius, 0), max(x0 - radius, 0)
        yb, xb = min(y1 + radius, h), min(x1 + radius, w)
        idx = self.index()[ya:yb, xa:xb]
        have = idx >= 0
        if use is not None:
            have &= use[ya:yb, xa:xb]
        costs = self.costs[planes]
        vals = np.zeros((*idx.shape, costs.shape[0]), np.float32)
        vals[have] = costs[:, idx[have]].T
        size = (2 * radius + 1, 2 * radius + 1)
        # All hypotheses in one call (channels last); OpenCV drops a single channel's axis.
        sums = cv2.boxFilter(vals, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
        sums = sums.reshape(*idx.shape, costs.shape[0])
        counts = cv2.boxFilter(have.astype(np.float32), -1, size, normalize=False,
                               borderType=cv2.BORDER_CONSTANT)
        sl = (slice(y0 - ya, y0 - ya + (y1 - y0)), slice(x0 - xa, x0 - xa + (x1 - x0)))
        return sums[sl], counts[sl]

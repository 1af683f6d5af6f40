"""Stereo: match ROIs between the retinas, triangulate them, measure disparities.

The eyes verge, so the retinas are not rectified. Everything here works with the
fundamental matrix F built from the two eye poses (``q^T F p = 0`` for a left pixel p and
its right match q, homogeneous, pixel centres at +0.5 as in roger_common.geometry).

Disparity (section 3.1: "the correlation between pairs of pixels, one in the filter
response of each retina") is measured per ROI and resolution in a small local
rectification: both LoG responses are resampled in a patch whose x axis runs along the
epipolar line through the ROI's centroid; the right patch is centred on the matched right
centroid. A sample's disparity is then the x shift that minimises the sum of squared
differences of the responses in a window, relative to the disparity of the centroids.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from roger_common.geometry import as_point, camera_ray, project_point, triangulate
from roger_common.types import CameraModel, EyePose
from roger_perception.config import PerceptionConfig
from roger_perception.segmentation import Blob


@dataclass(frozen=True)
class StereoMatch:
    """A ROI of the left retina with its partner in the right one.

    Attributes:
        left: Index into the left blobs.
        right: Index into the right blobs.
        position: Triangulated centroid, robot frame, metres.
        gap: Miss distance of the two rays, metres.
        cost: Matching cost (lower is better).
    """

    left: int
    right: int
    position: tuple[float, float, float]
    gap: float
    cost: float


def intrinsics(camera: CameraModel) -> np.ndarray:
    """3x3 pinhole matrix K of a retina (principal point at the image centre)."""
    return np.array([[camera.focal_px, 0.0, camera.width / 2.0],
                     [0.0, camera.focal_px, camera.height / 2.0],
                     [0.0, 0.0, 1.0]])


def fundamental_matrix(camera: CameraModel, left_pose: EyePose, right_pose: EyePose
                       ) -> np.ndarray:
    """F with ``q^T F p = 0`` for a left pixel p and the right pixel q of the same point."""
    r_rl = right_pose.rotation.T @ left_pose.rotation
    t = right_pose.rotation.T @ (np.asarray(left_pose.position, float)
                                 - np.asarray(right_pose.position, float))
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    k_inv = np.linalg.inv(intrinsics(camera))
    return k_inv.T @ (tx @ r_rl) @ k_inv


def epipolar_distance(f: np.ndarray, p_left: Sequence[float], q_right: Sequence[float]
                      ) -> float:
    """Distance (pixels) of the right pixel q from the epipolar line of the left pixel p."""
    line = f @ np.array([p_left[0], p_left[1], 1.0])
    norm = math.hypot(line[0], line[1])
    if norm < 1e-12:
        return float("inf")
    return abs(line[0] * q_right[0] + line[1] * q_right[1] + line[2]) / norm


def triangulate_pixels(camera: CameraModel, left_pose: EyePose, right_pose: EyePose,
                       p_left: Sequence[float], q_right: Sequence[float]
                       ) -> tuple[np.ndarray, float]:
    """Robot-frame point seen at left pixel p and right pixel q, and the rays' miss distance."""
    return triangulate(
        np.asarray(left_pose.position, float), camera_ray(camera, left_pose, *p_left),
        np.asarray(right_pose.position, float), camera_ray(camera, right_pose, *q_right),
    )


def match_blobs(left: Sequence[Blob], right: Sequence[Blob], camera: CameraModel,
                left_pose: EyePose, right_pose: EyePose, cfg: PerceptionConfig
                ) -> list[StereoMatch]:
    """Pair the ROIs of the two retinas, one to one, and triangulate each pair.

    A pair is admissible when the right centroid lies within ``epipolar_tol_px`` of the
    left centroid's epipolar line, the areas differ by at most ``max_area_ratio``, the mean
    intensities by at most ``max_intensity_diff``, and the rays meet (gap below
    ``max_ray_gap_m``) in front of both eyes. Admissible pairs are taken greedily by cost
    (sum of the three normalised differences). Left ROIs without a partner are dropped.

    Returns:
        The matches, sorted by left index.
    """
    f = fundamental_matrix(camera, left_pose, right_pose)
    candidates: list[StereoMatch] = []
    log_ratio_max = math.log(cfg.max_area_ratio) if cfg.max_area_ratio > 1 else 1e-9
    for i, bl in enumerate(left):
        for j, br in enumerate(right):
            epi = epipolar_distance(f, bl.centroid, br.centroid)
            ratio = abs(math.log(bl.area / br.area))
            dint = abs(bl.mean_intensity - br.mean_intensity)
            if epi > cfg.epipolar_tol_px or ratio > log_ratio_max + 1e-12 or (
                    dint > cfg.max_intensity_diff):
                continue
            point, gap = triangulate_pixels(camera, left_pose, right_pose, bl.centroid,
                                            br.centroid)
            if not np.all(np.isfinite(point)) or gap > cfg.max_ray_gap_m:
                continue
            if project_point(camera, left_pose, point)[2] <= 0 or project_point(
                    camera, right_pose, point)[2] <= 0:
                continue
            cost = (epi / cfg.epipolar_tol_px + ratio / log_ratio_max
                    + dint / cfg.max_intensity_diff)
            candidates.append(StereoMatch(i, j, as_point(point), gap, cost))
    candidates.sort(key=lambda m: (m.cost, m.left, m.right))
    used_l: set[int] = set()
    used_r: set[int] = set()
    out: list[StereoMatch] = []
    for m in candidates:
        if m.left in used_l or m.right in used_r:
            continue
        used_l.add(m.left)
        used_r.add(m.right)
        out.append(m)
    return sorted(out, key=lambda m: m.left)


def epipolar_direction(line: np.ndarray) -> np.ndarray:
    """Unit direction of an image line (a, b, c), oriented towards +u."""
    d = np.array([line[1], -line[0]], float)
    n = float(np.hypot(*d))
    if n < 1e-12:
        return np.array([1.0, 0.0])
    d /= n
    return -d if d[0] < 0 else d


def _patch(resp: np.ndarray, centre: Sequence[float], axis: np.ndarray, half: int,
           extra_x: int = 0, scale: float = 1.0) -> np.ndarray:
    """Resample ``resp`` in a patch centred on ``centre`` (u, v) whose x axis runs along
    ``axis``, one patch pixel spanning ``scale`` image pixels: (2 half + 1) rows,
    (2 (half + extra_x) + 1) columns; the centre lands on row ``half``, column
    ``half + extra_x``."""
    eu, ev = float(axis[0]) * scale, float(axis[1]) * scale
    cu, cv = float(centre[0]) - 0.5, float(centre[1]) - 0.5  # to array index coordinates
    hx = half + extra_x
    warp = np.array([[eu, -ev, cu - eu * hx + ev * half],
                     [ev, eu, cv - ev * hx - eu * half]])
    return cv2.warpAffine(resp, warp, (2 * hx + 1, 2 * half + 1),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def relative_disparities(left_resps: Sequence[np.ndarray], right_resps: Sequence[np.ndarray],
                         c_left: Sequence[float], c_right: Sequence[float], f: np.ndarray,
                         points: np.ndarray, half_windows: Sequence[int], search_px: int,
                         smoothness: float, magnification: float = 1.0) -> np.ndarray:
    """Disparity of each sample point relative to that of the ROI's centroids.

    Args:
        left_resps, right_resps: LoG responses, one (H, W) float32 array per resolution.
        c_left, c_right: Matched centroids (u, v) of the ROI in each retina.
        f: Fundamental matrix (left to right).
        points: (M, 2) sample points (u, v) in the left retina.
        half_windows: Correlation window half-size per resolution, pixels.
        search_px: Shifts -search_px..search_px are tried along the epipolar line.
        smoothness: Prior weight that pulls ambiguous samples to 0 (see config).
        magnification: Size of the ROI in the right retina over its size in the left
            (Z_left / Z_right, depths along each optical axis); the right patch is
            resampled at this scale so that the eyes' different distances to the object
            do not pass for relief.

    Returns:
        (K, M) float64 sub-pixel shifts along the epipolar line, one row per resolution,
        in (-search_px, search_px); NaN where the cost has no minimum inside the search
        range (the best shift is one of its ends: a failed match, not a measurement).
    """
    e_left = epipolar_direction(f.T @ np.array([c_right[0], c_right[1], 1.0]))
    e_right = epipolar_direction(f @ np.array([c_left[0], c_left[1], 1.0]))
    rel = np.asarray(points, float) - np.asarray(c_left, float)
    n_left = np.array([-e_left[1], e_left[0]])
    dx, dy = rel @ e_left, rel @ n_left
    hmax, r = int(max(half_windows)), int(search_px)
    half = math.ceil(max(np.abs(dx).max(), np.abs(dy).max())) + hmax + 1
    lp = np.stack([_patch(g, c_left, e_left, half) for g in left_resps])
    rp = np.stack([_patch(g, c_right, e_right, half, r, magnification) for g in right_resps])
    xi = np.rint(half + dx).astype(int)
    yi = np.rint(half + dy).astype(int)
    shifts = np.arange(-r, r + 1)
    out = np.empty((len(left_resps), len(xi)))
    cols = np.arange(len(xi))
    for k, h in enumerate(half_windows):
        # SSD(t) = sum_window (L(x, y) - R(x + t, y))^2 for every shift t, gathered at the
        # M samples only (the right patch has r extra columns on each side).
        d = np.arange(-h, h + 1)
        ys = yi[:, None, None] + d[None, :, None]
        xs = xi[:, None, None] + d[None, None, :]
        lwin = lp[k][ys, xs]
        rwin = rp[k][ys[None], xs[None] + r + shifts[:, None, None, None]]
        ssd = ((lwin[None] - rwin) ** 2).sum(axis=(2, 3), dtype=np.float64)
        energy = (lwin * lwin).sum(axis=(1, 2), dtype=np.float64)
        cost = ssd + smoothness * (shifts[:, None] ** 2) * (energy[None] + 1e-12)
        out[k] = _refine(cost, shifts, cols)
    return out


#: One ROI of ``relative_disparities_batch``: its matched centroids (u, v) in the left and
#: right retinas, its (M, 2) sample points (u, v) in the left retina, and its magnification
#: (see ``relative_disparities``).
RoiSamples = tuple[Sequence[float], Sequence[float], np.ndarray, float]


def relative_disparities_batch(left_resps: Sequence[np.ndarray],
                               right_resps: Sequence[np.ndarray], f: np.ndarray,
                               rois: Sequence[RoiSamples], half_windows: Sequence[int],
                               search_px: int, smoothness: float) -> list[np.ndarray]:
    """``relative_disparities`` of all the ROIs of a stereo pair at once.

    The same measurement without its per-call overhead (six patch resamplings and some
    forty small array operations per ROI, which cost more than the arithmetic): the image
    coordinates that ``_patch``'s affine warps map the needed patch pixels to are computed
    directly, for the correlation windows at the samples of every ROI only, each LoG
    response is resampled there by one ``cv2.remap`` (bilinear, replicated border, as the
    warp), and the costs, prior, argmin and parabola run over all the samples together.

    In the left patch of a ROI (x axis ``e_l``, centred on ``c_l``), patch pixel (x, y)
    relative to the centre lies at ``c_l + x e_l + y n_l`` (``n_l`` is ``e_l`` turned by
    +90 degrees); in the right patch (axis ``e_r``, scale m = magnification) at
    ``c_r + m (x e_r + y n_r)``. A sample at offset (p, q) in the left patch (its rounded
    coordinates along and across the epipolar line) needs the left pixels (p + a, q + b)
    and the right pixels (p + a + t, q + b) for |a|, |b| <= h and |t| <= search_px.

    The window sums are expanded, SSD(t) = sum L^2 + sum R_t^2 - 2 sum L R_t, in float64
    (``relative_disparities`` sums float32 squared differences in float64): the same costs
    up to rounding.

    Args:
        left_resps, right_resps: LoG responses, one (H, W) float32 array per resolution.
        f: Fundamental matrix (left to right).
        rois: One (c_left, c_right, points, magnification) per ROI (see RoiSamples).
        half_windows: Correlation window half-size per resolution, pixels.
        search_px: Shifts -search_px..search_px are tried along the epipolar line.
        smoothness: Prior weight that pulls ambiguous samples to 0 (see config).

    Returns:
        One (K, M_i) float64 array per ROI: what ``relative_disparities`` returns for it,
        up to interpolation noise (the resampling coordinates are rounded to float32 here
        and computed by the warp there: a few ten-thousandths of a pixel of disparity on
        the simulator's frames).

    Raises:
        ValueError: When there is not one right response and one half window per left
            response.
    """
    n_res = len(left_resps)
    if len(right_resps) != n_res or len(half_windows) != n_res:
        raise ValueError("need one right response and one half window per left response")
    counts = np.array([len(roi[2]) for roi in rois], dtype=np.intp)
    total = int(counts.sum())
    if total == 0 or n_res == 0:
        return [np.empty((n_res, int(m))) for m in counts]
    c_left = np.array([roi[0] for roi in rois], float).reshape(-1, 2)
    c_right = np.array([roi[1] for roi in rois], float).reshape(-1, 2)
    ones = np.ones((len(rois), 1))
    # Rows: F^T q for each right centroid q, F p for each left centroid p.
    e_left = _directions(np.hstack([c_right, ones]) @ f)
    e_right = _directions(np.hstack([c_left, ones]) @ f.T)
    e_right *= np.array([roi[3] for roi in rois], float)[:, None]
    roi_of = np.repeat(np.arange(len(rois)), counts)
    points = np.concatenate([np.asarray(roi[2], float).reshape(-1, 2) for roi in rois])
    el, er = e_left[roi_of], e_right[roi_of]
    rel = points - c_left[roi_of]
    dx = rel[:, 0] * el[:, 0] + rel[:, 1] * el[:, 1]
    dy = rel[:, 1] * el[:, 0] - rel[:, 0] * el[:, 1]
    # Rounded as in relative_disparities' patch, centred on ``half``: rint(half + d) -
    # half is not rint(d) at ties (rint rounds them to even).
    hmax, r = int(max(half_windows)), int(search_px)
    extent = np.zeros(len(rois))
    starts = np.cumsum(counts) - counts
    extent[counts > 0] = np.maximum.reduceat(np.maximum(np.abs(dx), np.abs(dy)),
                                             starts[counts > 0])
    half = (np.ceil(extent) + hmax + 1)[roi_of]
    p = (np.rint(half + dx) - half)[:, None]
    q = (np.rint(half + dy) - half)[:, None]
    # Image (array index) coordinates of the windows of the largest half size; the other
    # resolutions use their middle.
    lmx, lmy = _grid(c_left[roi_of] - 0.5 + p * el + q * _normal(el), el, hmax, hmax)
    rmx, rmy = _grid(c_right[roi_of] - 0.5 + p * er + q * _normal(er), er, hmax, hmax + r)
    shifts = np.arange(-r, r + 1)
    out = np.empty((n_res, total))
    cols = np.arange(total)
    for k, h in enumerate(half_windows):
        h = int(h)
        n = 2 * h + 1
        rows = slice(hmax - h, hmax + h + 1)
        lwin = _remap(left_resps[k], lmx[:, rows, rows], lmy[:, rows, rows])
        wide = slice(hmax - h, hmax + h + 2 * r + 1)
        rwide = _remap(right_resps[k], rmx[:, rows, wide], rmy[:, rows, wide])
        lw, rw = lwin.astype(np.float64), rwide.astype(np.float64)
        energy = np.einsum("nba,nba->n", lw, lw)
        # Window sums of R^2 and of L R for every shift t (column offset t + r in rwide).
        rr = sliding_window_view(np.einsum("nba,nba->na", rw, rw), n, axis=1).sum(axis=2)
        lr = np.matmul(sliding_window_view(rw, n, axis=2), lw[..., None])[..., 0].sum(axis=1)
        ssd = (energy[:, None] + rr - 2.0 * lr).T
        cost = ssd + smoothness * (shifts[:, None] ** 2) * (energy[None] + 1e-12)
        out[k] = _refine(cost, shifts, cols)
    return list(np.split(out, np.cumsum(counts)[:-1], axis=1))


def _directions(lines: np.ndarray) -> np.ndarray:
    """``epipolar_direction`` of each row (a, b, c) of ``lines``, as rows."""
    d = np.stack([lines[:, 1], -lines[:, 0]], axis=1)
    norm = np.hypot(d[:, 0], d[:, 1])
    flat = norm < 1e-12
    d /= np.where(flat, 1.0, norm)[:, None]
    d[d[:, 0] < 0] *= -1.0
    d[flat] = (1.0, 0.0)
    return d


def _normal(axis: np.ndarray) -> np.ndarray:
    """Each row (x, y) of ``axis`` turned by +90 degrees: (-y, x)."""
    return np.stack([-axis[:, 1], axis[:, 0]], axis=1)


def _grid(centre: np.ndarray, axis: np.ndarray, half_rows: int, half_cols: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """float32 maps (N, 2 half_rows + 1, 2 half_cols + 1) of ``centre + a axis + b normal``
    for row b and column a of each of the N windows."""
    a = np.arange(-half_cols, half_cols + 1, dtype=float)
    b = np.arange(-half_rows, half_rows + 1, dtype=float)
    ex, ey = axis[:, :1], axis[:, 1:]
    shape = (len(centre), len(b), len(a))
    mx, my = np.empty(shape, np.float32), np.empty(shape, np.float32)
    np.add((centre[:, :1] - b * ey)[:, :, None], (a * ex)[:, None, :], out=mx,
           casting="same_kind")
    np.add((centre[:, 1:] + b * ex)[:, :, None], (a * ey)[:, None, :], out=my,
           casting="same_kind")
    return mx, my


def _remap(resp: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """``resp`` at the array coordinates (map_x, map_y), float32 of any shape (N, rows,
    cols): bilinear, replicated border, as ``_patch``'s warp."""
    shape = map_x.shape
    flat = (shape[0] * shape[1], shape[2])
    out = cv2.remap(resp, np.ascontiguousarray(map_x).reshape(flat),
                    np.ascontiguousarray(map_y).reshape(flat), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(shape)


def _refine(cost: np.ndarray, shifts: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sub-pixel shift of the minimum of each column of ``cost`` (one row per shift):
    a parabola through the best shift and its neighbours, its step clipped to +-0.5; NaN
    where the best shift is an end of the range."""
    best = np.argmin(cost, axis=0)
    s = shifts[best].astype(float)
    inner = (best > 0) & (best < len(shifts) - 1)
    c0 = cost[best[inner], cols[inner]]
    cm = cost[best[inner] - 1, cols[inner]]
    cp = cost[best[inner] + 1, cols[inner]]
    den = cm - 2.0 * c0 + cp
    ok = den > 1e-18
    s[inner] += np.clip(np.where(ok, 0.5 * (cm - cp) / np.where(ok, den, 1.0), 0.0),
                        -0.5, 0.5)
    s[~inner] = np.nan
    return s


def relief_per_pixel(camera: CameraModel, left_pose: EyePose, right_pose: EyePose,
                     position: Sequence[float]) -> float:
    """Depth change (metres) per pixel of disparity change at a robot-frame point.

    From disparity = f b / Z: dZ = Z_left Z_right / (f b) per pixel, b being the baseline's
    component perpendicular to the line of sight to the point. NaN when undefined.
    """
    p = np.asarray(position, float)
    cl, cr = np.asarray(left_pose.position, float), np.asarray(right_pose.position, float)
    sight = p - (cl + cr) / 2.0
    sight /= np.linalg.norm(sight)
    base = cl - cr
    b_perp = float(np.linalg.norm(base - (base @ sight) * sight))
    z_l = project_point(camera, left_pose, p)[2]
    z_r = project_point(camera, right_pose, p)[2]
    if b_perp < 1e-9 or z_l <= 0 or z_r <= 0:
        return float("nan")
    return z_l * z_r / (camera.focal_px * b_perp)

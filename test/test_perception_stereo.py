"""Stereo: epipolar geometry, ROI pairing, triangulation, disparity and S (equation 3).

That the core imports without ROS is checked elsewhere.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from perception_synth import CENTRE_GAZE, camera_model, eye_poses, make_frame, table1_objects

from roger_common.geometry import look_rotation, project_point
from roger_common.types import CameraModel, EyePose
from roger_perception.config import PerceptionConfig
from roger_perception.features import stereo_feature
from roger_perception.log_filter import log_kernel, log_pyramid, log_response
from roger_perception.segmentation import segment_retina
from roger_perception.stereo import (
    RoiSamples,
    epipolar_direction,
    epipolar_distance,
    fundamental_matrix,
    match_blobs,
    relative_disparities,
    relative_disparities_batch,
    relief_per_pixel,
    triangulate_pixels,
)

CAMERA = camera_model(128)


def _parallel_eyes() -> tuple[EyePose, EyePose]:
    """Both eyes looking straight ahead (+x): rectified, epipolar lines are image rows."""
    poses = []
    for y in (0.08, -0.08):
        p = np.array([0.0, y, 0.4])
        poses.append(EyePose(position=p, rotation=look_rotation(p, p + [1.0, 0.0, 0.0])))
    return poses[0], poses[1]


def _shifted(resp: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """right(x, y) = left(x + shift(y), y): each row seen ``shift`` px further left."""
    h, w = resp.shape
    map_x = (np.arange(w)[None, :] + shift[:, None]).astype(np.float32)
    map_y = np.repeat(np.arange(h, dtype=np.float32)[:, None], w, axis=1)
    return cv2.remap(resp, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _texture_response(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((128, 128)).astype(np.float32), (0, 0), 1.0)
    return log_response(img, log_kernel(1.5))


@pytest.mark.parametrize("gaze", [(0.9, 0.0, 0.05), (0.7, 0.3, 0.0), (1.1, -0.2, 0.1)])
def test_projections_of_a_point_satisfy_the_epipolar_constraint(gaze) -> None:
    left, right = eye_poses(gaze)
    f = fundamental_matrix(CAMERA, left, right)
    rng = np.random.default_rng(0)
    for _ in range(20):
        point = np.asarray(gaze) + rng.normal(0.0, 0.1, 3)
        p = project_point(CAMERA, left, point)[:2]
        q = project_point(CAMERA, right, point)[:2]
        assert epipolar_distance(f, p, q) < 1e-6
        assert epipolar_distance(f, p, (q[0], q[1] + 3.0)) > 1.0
        found, gap = triangulate_pixels(CAMERA, left, right, p, q)
        np.testing.assert_allclose(found, point, atol=1e-9)
        assert gap < 1e-9


def test_relative_disparities_recover_a_known_relief_and_equation_3() -> None:
    left, right = _parallel_eyes()
    f = fundamental_matrix(CAMERA, left, right)
    lr = _texture_response(1)
    # Rows above 64 lie 3 px apart in the two retinas, rows below 5 px.
    rr = _shifted(lr, np.where(np.arange(128) < 64, 3.0, 5.0))
    pts = np.array([[u, v] for u in (50, 60, 70, 80) for v in (50, 56, 72, 78)], float) + 0.5
    s = relative_disparities([lr], [rr], (64.0, 64.0), (61.0, 64.0), f, pts, [3], 3, 0.0)
    assert s.shape == (1, 16)
    top = pts[:, 1] < 64
    np.testing.assert_allclose(s[0, top], 0.0, atol=0.15)
    np.testing.assert_allclose(s[0, ~top], -2.0, atol=0.15)
    # Equation 3 with s_max = 3 px: half the samples at 0, half at -2/3 -> variance 1/9.
    assert float(stereo_feature(s[0], 3.0)[0]) == pytest.approx(1.0 / 9.0, abs=0.01)


def test_a_flat_shift_has_no_relief() -> None:
    left, right = _parallel_eyes()
    f = fundamental_matrix(CAMERA, left, right)
    lr = _texture_response(2)
    rr = _shifted(lr, np.full(128, 2.4))
    pts = np.random.default_rng(3).uniform(40, 88, (32, 2))
    s = relative_disparities([lr, lr], [rr, rr], (64.0, 64.0), (61.6, 64.0), f, pts, [2, 4], 3,
                             0.02)
    assert s.shape == (2, 32)
    assert np.abs(s).max() < 0.2
    assert float(stereo_feature(s[0], 3.0)[0]) < 1e-3


def test_the_smoothness_prior_settles_the_aperture_problem() -> None:
    # Horizontal stripes: any shift along the (horizontal) epipolar line fits equally well.
    left, right = _parallel_eyes()
    f = fundamental_matrix(CAMERA, left, right)
    stripes = np.repeat(np.sin(np.arange(128) / 2.0)[:, None], 128, axis=1).astype(np.float32)
    rng = np.random.default_rng(4)
    noisy = stripes + rng.normal(0.0, 0.01, stripes.shape).astype(np.float32)
    pts = rng.uniform(40, 88, (32, 2))
    s = relative_disparities([stripes], [noisy], (64.0, 64.0), (64.0, 64.0), f, pts, [3], 3,
                             0.05)
    np.testing.assert_allclose(s, 0.0, atol=0.5)  # no NaN either: every sample settled
    loose = relative_disparities([stripes], [noisy], (64.0, 64.0), (64.0, 64.0), f, pts, [3], 3,
                                 0.0)
    # Without the prior, ambiguous samples wander off, many to the ends of the search
    # range: failed matches (NaN), left out of equation 3.
    assert np.isnan(loose).any() or np.nanmax(np.abs(loose)) > np.abs(s).max()


def _tilted_eyes() -> tuple[EyePose, EyePose]:
    """Both eyes looking straight ahead, the baseline along a diagonal of the retinas:
    epipolar lines at about 45 degrees."""
    poses = []
    for y, z in ((0.08, 0.48), (-0.08, 0.32)):
        p = np.array([0.0, y, z])
        poses.append(EyePose(position=p, rotation=look_rotation(p, p + [1.0, 0.0, 0.0])))
    return poses[0], poses[1]


def _batch_matches_single(left_log: list[np.ndarray], right_log: list[np.ndarray],
                          f: np.ndarray, rois: list[RoiSamples], cfg: PerceptionConfig
                          ) -> int:
    """Assert the batch gives, ROI by ROI, what relative_disparities gives; the number of
    disparities measured (not NaN)."""
    windows = [max(1, round(cfg.match_window_sigmas * s)) for s in cfg.log_sigmas]
    got = relative_disparities_batch(left_log, right_log, f, rois, windows,
                                     cfg.stereo_search_px, cfg.stereo_smoothness)
    assert len(got) == len(rois)
    measured = 0
    for (c_left, c_right, points, magnification), batch in zip(rois, got, strict=True):
        if len(points) == 0:
            assert batch.shape == (3, 0)
            continue
        single = relative_disparities(left_log, right_log, c_left, c_right, f, points,
                                      windows, cfg.stereo_search_px, cfg.stereo_smoothness,
                                      magnification)
        assert batch.shape == single.shape
        np.testing.assert_array_equal(np.isnan(batch), np.isnan(single))
        # Interpolation noise only (the resampling coordinates are rounded differently).
        np.testing.assert_allclose(batch, single, rtol=0.0, atol=0.02)
        measured += int(np.isfinite(single).sum())
    return measured


@pytest.mark.parametrize("gaze", [CENTRE_GAZE, (0.7, 0.3, 0.0), (1.1, -0.2, 0.1),
                                  (0.6, -0.25, 0.3)])
def test_the_batch_measures_every_roi_as_the_single_roi_function(gaze) -> None:
    cfg = PerceptionConfig()
    frame = make_frame(table1_objects("cube"), gaze=gaze, seed=6)
    left_log, right_log = log_pyramid(frame.left, cfg), log_pyramid(frame.right, cfg)
    _, left = segment_retina(frame.left, cfg)
    _, right = segment_retina(frame.right, cfg)
    matches = match_blobs(left, right, frame.camera, frame.left_pose, frame.right_pose, cfg)
    assert len(matches) >= 3
    rng = np.random.default_rng(7)
    rois: list[RoiSamples] = []
    for m in matches:
        u0, v0, u1, v1 = left[m.left].bbox
        points = np.stack([rng.uniform(u0 - 3, u1 + 3, 24), rng.uniform(v0 - 3, v1 + 3, 24)],
                          axis=1)
        rois.append((left[m.left].centroid, right[m.right].centroid, points,
                     float(rng.uniform(0.8, 1.25))))
    # A ROI in a corner (windows past the retina's edge: the border is replicated), one
    # with no samples, and one with a single sample.
    rois.append(((4.0, 5.0), (2.5, 6.0), rng.uniform(0.0, 12.0, (10, 2)), 1.1))
    rois.append(((64.0, 64.0), (60.0, 64.0), np.empty((0, 2)), 1.0))
    rois.append(((40.0, 90.0), (37.0, 91.0), np.array([[42.3, 88.9]]), 0.9))
    f = fundamental_matrix(frame.camera, frame.left_pose, frame.right_pose)
    assert _batch_matches_single(left_log, right_log, f, rois, cfg) > 100


def test_the_batch_follows_steep_epipolar_lines_and_rounds_ties_alike() -> None:
    cfg = PerceptionConfig()
    frame = make_frame(table1_objects("sphere"), gaze=CENTRE_GAZE, seed=8)
    left_log, right_log = log_pyramid(frame.left, cfg), log_pyramid(frame.right, cfg)
    rng = np.random.default_rng(9)
    for (left_pose, right_pose), steep in ((_tilted_eyes(), True), (_parallel_eyes(), False)):
        f = fundamental_matrix(CAMERA, left_pose, right_pose)
        rois: list[RoiSamples] = []
        for _ in range(6):
            # Integer centroids and samples at pixel centres: along a row (parallel eyes)
            # the samples lie exactly half a pixel off the centroid, a tie when rounded.
            c_left = rng.integers(20, 108, 2).astype(float)
            c_right = c_left + rng.integers(-6, 7, 2)
            points = c_left + rng.integers(-15, 16, (20, 2)) + 0.5
            rois.append((tuple(c_left), tuple(c_right), points, float(rng.uniform(0.8, 1.25))))
            e = epipolar_direction(f.T @ np.array([c_right[0], c_right[1], 1.0]))
            assert (abs(e[1]) > 0.5) == steep  # more than 30 degrees off the rows, or none
        assert _batch_matches_single(left_log, right_log, f, rois, cfg) > 100


def test_blobs_are_paired_with_the_same_object_in_the_other_retina() -> None:
    objects = table1_objects("cylinder")
    frame = make_frame(objects, gaze=CENTRE_GAZE, seed=5)
    cfg = PerceptionConfig()
    _, left = segment_retina(frame.left, cfg)
    _, right = segment_retina(frame.right, cfg)
    matches = match_blobs(left, right, frame.camera, frame.left_pose, frame.right_pose, cfg)
    assert len(matches) == 4
    for m in matches:
        bl, br = left[m.left], right[m.right]
        lab_l = frame.left_labels[bl.bbox[1]:bl.bbox[3], bl.bbox[0]:bl.bbox[2]][bl.mask]
        lab_r = frame.right_labels[br.bbox[1]:br.bbox[3], br.bbox[0]:br.bbox[2]][br.mask]
        assert np.bincount(lab_l + 1).argmax() == np.bincount(lab_r + 1).argmax()
        assert m.gap < cfg.max_ray_gap_m
    assert match_blobs(left, [], frame.camera, frame.left_pose, frame.right_pose, cfg) == []


def test_relief_per_pixel_follows_z_squared_over_f_b() -> None:
    left, right = _parallel_eyes()
    cam = CameraModel(width=128, height=128, focal_px=100.0)
    for z in (0.5, 1.0):
        point = (z, 0.0, 0.4)
        assert relief_per_pixel(cam, left, right, point) == pytest.approx(z * z / (100 * 0.16))

"""Features of a ROI, equations 1-5 (roger_perception.features and Perception).

That the core imports without ROS is checked elsewhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from perception_synth import (
    CENTRE_GAZE,
    SPREAD,
    TABLE1,
    Shape,
    make_frame,
    nearest_object,
    table1_objects,
)

from roger_common.types import FEATURE_DIM, FEATURE_NAMES, WEIGHT_INDEX, HapticReading, feature_dim
from roger_perception.config import PerceptionConfig
from roger_perception.features import (
    assemble,
    g_max,
    intensity_texture,
    sample_at,
    size_feature,
    stereo_feature,
    vicinity_magnitude,
    weight_feature,
)
from roger_perception.log_filter import kernel_edge_peak, log_kernel, log_response
from roger_perception.perception import Perception

I_IDX = [FEATURE_NAMES.index(n) for n in ("I1", "I2", "I3")]
D_IDX = FEATURE_NAMES.index("D")


def _by_object(rois, objects):
    """ROIs keyed by the index of the nearest object; every object must be seen once."""
    out = {nearest_object(r.position, objects): r for r in rois}
    assert sorted(out) == list(range(len(objects))), [r.position for r in rois]
    return out


# --- equations on hand-computed values ------------------------------------------------------

def test_equations_1_and_2_on_hand_computed_samples() -> None:
    i_k, t_k = intensity_texture(np.array([0.1, 0.2, 0.3, 0.4]), 0.4)
    # G / G_max = 0.25, 0.5, 0.75, 1 -> mean 0.625, variance 0.078125
    assert float(i_k) == pytest.approx(0.625)
    assert float(t_k) == pytest.approx(0.078125)


def test_equations_1_and_2_clip_and_work_per_resolution() -> None:
    samples = np.array([[0.2, 0.2, 0.8, 0.8], [0.0, 0.0, 0.0, 0.0]])
    i_k, t_k = intensity_texture(samples, np.array([0.4, 1.0]))
    # row 0: 0.5, 0.5, 1 (clipped from 2), 1 -> mean 0.75, variance 0.0625
    np.testing.assert_allclose(i_k, [0.75, 0.0])
    np.testing.assert_allclose(t_k, [0.0625, 0.0])


def test_equation_3_on_hand_computed_disparities() -> None:
    # s / s_max = 0.5, -0.5, 1, 0 -> mean 0.25 -> squared deviations .0625 .5625 .5625 .0625
    s, known = stereo_feature(np.array([1.0, -1.0, 2.0, 0.0]), 2.0)
    assert float(s) == pytest.approx(0.3125) and bool(known)
    # Clipped to [-1, 1]: the largest possible value is 1.
    assert float(stereo_feature(np.array([5.0, -5.0]), 2.0)[0]) == pytest.approx(1.0)
    assert float(stereo_feature(np.full(7, 1.3), 2.0)[0]) == pytest.approx(0.0)


def test_equation_3_leaves_failed_matches_out_and_needs_enough_samples() -> None:
    # A failed match (NaN) is not a measurement: M and N count the valid samples only.
    s, known = stereo_feature(np.array([1.0, np.nan, -1.0, 2.0, np.nan, 0.0]), 2.0)
    assert float(s) == pytest.approx(0.3125) and bool(known)
    per_k, known_k = stereo_feature(np.array([[1.0, -1.0, 2.0, 0.0],
                                              [np.nan, np.nan, np.nan, 0.5]]), 2.0, min_valid=2)
    assert known_k.tolist() == [True, False] and per_k[1] == 0.0


def test_equations_4_and_5() -> None:
    assert size_feature(0.07, 0.35) == pytest.approx(0.2)
    assert size_feature(1.0, 0.35) == 1.0 and size_feature(float("nan"), 0.35) == 0.0
    assert weight_feature(1.5, 2.0) == pytest.approx(0.75)
    assert weight_feature(3.0, 2.0) == 1.0 and weight_feature(-1.0, 2.0) == 0.0


def test_equation_1_on_a_synthetic_edge_response_gives_contrast_over_contrast_max() -> None:
    cfg = PerceptionConfig(contrast_max=0.5)
    sigma, size = cfg.log_sigmas[1], cfg.kernel_sizes()[1]
    img = np.zeros((60, 60), np.float32)
    img[:, 30:] = 0.3  # straight edge of contrast 0.3 against the dark ground
    resp = log_response(img, log_kernel(sigma, size))
    vic = vicinity_magnitude(resp, 2)
    points = np.column_stack([np.full(16, 30.5), np.linspace(10, 50, 16)])
    assert g_max(cfg)[1] == pytest.approx(0.5 * kernel_edge_peak(log_kernel(sigma, size)))
    i_k, t_k = intensity_texture(sample_at(vic, points), g_max(cfg)[1])
    assert float(i_k) == pytest.approx(0.3 / 0.5, rel=1e-3)
    assert float(t_k) == pytest.approx(0.0, abs=1e-8)


def test_assemble_follows_feature_names_and_marks_weight_unknown() -> None:
    feats, known = assemble(np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.5, 0.6]),
                            np.array([0.7, 0.8, 0.9]), 0.25, None)
    assert feats.dtype == np.float32 and feats.shape == (FEATURE_DIM,)
    for name, value in zip(("I1", "T2", "S3", "D"), (0.1, 0.5, 0.9, 0.25), strict=True):
        assert feats[FEATURE_NAMES.index(name)] == pytest.approx(value)
    assert not known[WEIGHT_INDEX] and feats[WEIGHT_INDEX] == 0.0
    assert known.sum() == FEATURE_DIM - 1
    feats, known = assemble(np.zeros(3), np.zeros(3), np.zeros(3), 0.0, 0.6)
    assert known.all() and feats[WEIGHT_INDEX] == pytest.approx(0.6)


# --- perceived features keep the order of the world values ----------------------------------

def test_perceived_intensity_rises_with_world_intensity_roughly_proportionally() -> None:
    objects = table1_objects()
    rois = _by_object(Perception().process(make_frame(objects, gaze=CENTRE_GAZE)), objects)
    intensities = np.array([o.intensity for o in objects])  # 99, 79, 69, 59
    perceived = np.array([rois[i].features[I_IDX] for i in range(4)])  # (object, k)
    for k in range(3):
        assert np.all(np.diff(perceived[:, k]) < 0), perceived[:, k]
    ratio = perceived[:, 0] / intensities
    assert ratio.max() / ratio.min() < 1.35, ratio
    assert 0.4 < perceived[0, 0] <= 1.0  # Table 1: 0.83 for intensity 99


def test_perceived_size_keeps_the_order_of_world_sizes() -> None:
    sizes = (0.06, 0.09, 0.12)
    objects = [Shape("sphere", x, y, s, 90.0) for s, (x, y) in zip(sizes, SPREAD, strict=False)]
    perception = Perception(PerceptionConfig())
    frame = make_frame(objects, gaze=CENTRE_GAZE)
    rois = _by_object(perception.process(frame), objects)
    d = np.array([rois[i].features[D_IDX] for i in range(3)])
    assert np.all(np.diff(d) > 0), d
    # A sphere's silhouette is a disc: the side of a square of its area is sqrt(pi) / 2 of
    # its diameter.
    np.testing.assert_allclose(d * perception.d_max(frame.camera) / (math.sqrt(math.pi) / 2),
                               sizes, rtol=0.25)


def test_perceived_weight_keeps_order_and_stays_with_the_object() -> None:
    objects = table1_objects()
    perception = Perception()
    first = _by_object(perception.process(make_frame(objects, gaze=CENTRE_GAZE)), objects)
    assert not any(r.known[WEIGHT_INDEX] or r.features[WEIGHT_INDEX] for r in first.values())
    # Haptic improvements on objects 0, 1 and 3, touching each on its near side.
    for i in (0, 1, 3):
        o = objects[i]
        contact = (o.x - o.size / 2.0, o.y, o.size / 2.0)
        reading = HapticReading(arm=0, contact=True, position=contact, weight=TABLE1[i][1])
        perception.process(make_frame(objects, gaze=(o.x, o.y, 0.05), haptic=reading, seed=i))
    later = _by_object(perception.process(make_frame(objects, gaze=CENTRE_GAZE, seed=9)),
                       objects)
    w = {i: later[i].features[WEIGHT_INDEX] for i in (0, 1, 3)}
    assert all(later[i].known[WEIGHT_INDEX] for i in (0, 1, 3))
    assert w[0] > w[1] > w[3]
    assert w[0] == pytest.approx(1.5 / 2.0) and w[3] == pytest.approx(0.5 / 2.0)
    assert not later[2].known[WEIGHT_INDEX] and later[2].features[WEIGHT_INDEX] == 0.0


def test_haptic_reading_without_contact_is_not_a_weight() -> None:
    objects = table1_objects()
    o = objects[0]
    reading = HapticReading(arm=0, contact=False, position=o.centre, weight=float("nan"))
    rois = _by_object(Perception().process(make_frame(objects, haptic=reading,
                                                      gaze=CENTRE_GAZE)), objects)
    assert not rois[0].known[WEIGHT_INDEX] and rois[0].tactile == 0.0


def _fixated_features(objects: list[Shape], seed: int) -> np.ndarray:
    """Features of each object with both eyes fixating it (features are taken after the
    controllers converge on the ROI in focus, section 4.1)."""
    perception = Perception()
    out = []
    for i, o in enumerate(objects):
        perception.reset()
        frame = make_frame(objects, gaze=(o.x, o.y, 0.05), seed=seed + i)
        rois = [r for r in perception.process(frame) if nearest_object(r.position, objects) == i]
        assert len(rois) == 1
        out.append(rois[0].features)
    return np.array(out)


def test_same_object_at_two_positions_is_closer_to_itself_than_to_the_others() -> None:
    # Upright cylinders (their silhouette does not depend on the bearing; a cube's width and
    # relief and a sphere's rim shading do, see docs/perception.md), at the four places of a
    # row, swapped in pairs: every object is seen at a second place and bearing.
    reference = _fixated_features(table1_objects("cylinder"), seed=0)
    swapped = (SPREAD[2], SPREAD[3], SPREAD[0], SPREAD[1])
    moved = _fixated_features(table1_objects("cylinder", positions=swapped), seed=10)
    for i in range(4):
        dist = np.linalg.norm(reference - moved[i], axis=1)
        assert int(np.argmin(dist)) == i, (i, dist)


def test_visual_improvement_lowers_the_spread_of_repeated_measurements() -> None:
    objects = table1_objects()
    perception = Perception()

    def spread(exposures: int) -> float:
        runs = []
        for seed in range(6):
            perception.reset()
            frame = make_frame(objects, gaze=CENTRE_GAZE, exposures=exposures, seed=seed)
            rois = _by_object(perception.process(frame), objects)
            runs.append([rois[i].features for i in range(4)])
        return float(np.array(runs).std(axis=0).mean())

    one, sixteen = spread(1), spread(16)
    assert sixteen < one / 1.5, (one, sixteen)


def test_features_lie_in_the_unit_interval_and_repeat_exactly() -> None:
    objects = [Shape("cube", 0.7, 0.2, 0.12, 200.0, yaw=0.4),
               Shape("cylinder", 0.9, -0.05, 0.08, 40.0),
               Shape("sphere", 1.1, -0.3, 0.15, 255.0)]
    frame = make_frame(objects, gaze=(0.9, 0.0, 0.05), seed=4)
    a = Perception().process(frame)
    b = Perception(seed=7).process(frame)
    assert len(a) == 3
    for ra, rb in zip(a, b, strict=True):
        dim = feature_dim(Perception().config.features)
        assert ra.features.dtype == np.float32 and ra.features.shape == (dim,)
        assert np.all((ra.features >= 0.0) & (ra.features <= 1.0))
        np.testing.assert_array_equal(ra.features, rb.features)
        assert ra.position == rb.position

"""Regions of interest: segmentation, positions, activation and state (Perception).

That the core imports without ROS is checked elsewhere.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from perception_synth import CENTRE_GAZE, SPREAD, Shape, make_frame, nearest_object, table1_objects

from roger_common.errors import MessageError
from roger_common.types import HapticReading
from roger_perception.activation import (
    MotionView,
    motion_image,
    visual_motion,
    visual_motion_batch,
)
from roger_perception.config import PerceptionConfig
from roger_perception.grouping import absorb_slivers, adjacency, group_fragments
from roger_perception.perception import Perception
from roger_perception.plane_sweep import SampledCosts, region_curves
from roger_perception.segmentation import (
    _median,
    contour_samples,
    deepest_defect,
    ground_notches,
    segment_retina,
    split_at_notches,
)


def test_ground_alone_gives_no_roi() -> None:
    assert Perception().process(make_frame([], seed=1)) == []
    assert Perception().process(make_frame([], noise_std=0.03, seed=2)) == []


def test_one_roi_per_object_with_bbox_on_it_and_position_near_its_centre() -> None:
    objects = table1_objects("cylinder")
    frame = make_frame(objects, gaze=CENTRE_GAZE, seed=3)
    rois = Perception().process(frame)
    assert [r.roi_id for r in rois] == list(range(4))
    seen = set()
    for r in rois:
        i = nearest_object(r.position, objects)
        seen.add(i)
        u0, v0, u1, v1 = r.bbox
        assert 0 <= u0 < u1 <= 128 and 0 <= v0 < v1 <= 128
        labels = frame.left_labels[v0:v1, u0:u1]
        assert np.mean(labels == i) > 0.5  # the box holds mostly that object
        assert np.linalg.norm(np.asarray(r.position) - objects[i].centre) < 0.02
        assert 0.0 < r.retinal_size < 0.05
        albedo = objects[i].intensity / 255.0  # shaded by 0.6..1 in the synthetic renderer
        assert 0.5 * albedo < r.mean_intensity < albedo
    assert seen == {0, 1, 2, 3}


def test_position_stays_put_when_the_eyes_move() -> None:
    objects = table1_objects("cube")
    perception = Perception()
    positions = []
    for gaze in (CENTRE_GAZE, (0.85, 0.2, 0.05), (0.95, -0.15, 0.0)):
        perception.reset()
        rois = perception.process(make_frame(objects, gaze=gaze, seed=5))
        positions.append({nearest_object(r.position, objects): np.asarray(r.position)
                          for r in rois})
    common = set(positions[0]) & set(positions[1]) & set(positions[2])
    assert len(common) >= 2
    for i in common:
        for p in positions[1:]:
            # Depth comes from a plane sweep in 1 px steps refined by a parabola: about
            # 2 cm at 0.85 m, and the background level (a low quantile of the retina) lets
            # a little more of the shaded rim in; the attention node needs < 5 cm.
            assert np.linalg.norm(p[i] - positions[0][i]) < 0.04


def test_small_regions_are_not_rois() -> None:
    objects = [Shape("sphere", 0.9, 0.0, 0.1, 90.0)]
    frame = make_frame(objects, seed=6)
    assert len(Perception().process(frame)) == 1
    area = int(segment_retina(frame.left, PerceptionConfig())[1][0].area)
    strict = PerceptionConfig(min_roi_pixels=area + 1)
    assert Perception(strict).process(frame) == []


def test_border_margin_drops_cut_rois_only_when_asked() -> None:
    objects = [Shape("cylinder", 0.85, y, 0.1, 90.0) for y in (0.0, 0.4)]
    frame = make_frame(objects, gaze=(0.85, -0.05, 0.05), seed=7)
    keep = Perception().process(frame)
    drop = Perception(PerceptionConfig(border_margin_px=1)).process(frame)
    assert len(keep) == 2 and len(drop) == 1
    assert nearest_object(drop[0].position, objects) == 0


def test_contour_samples_are_m_points_on_the_roi_boundary() -> None:
    frame = make_frame([Shape("sphere", 0.9, 0.0, 0.12, 90.0)], noise_std=0.0)
    blob = segment_retina(frame.left, PerceptionConfig())[1][0]
    for m in (8, 32, 200):  # M does not depend on the ROI's size
        pts = contour_samples(blob, m)
        assert pts.shape == (m, 2)
        u0, v0, u1, v1 = blob.bbox
        assert np.all((pts[:, 0] > u0) & (pts[:, 0] < u1) & (pts[:, 1] > v0) & (pts[:, 1] < v1))
        cols = np.floor(pts[:, 0]).astype(int) - u0
        rows = np.floor(pts[:, 1]).astype(int) - v0
        assert blob.mask[rows, cols].all()


def test_mapping_status_and_its_effect_on_activation() -> None:
    objects = table1_objects("cylinder")
    frame = make_frame(objects, gaze=CENTRE_GAZE, seed=8)
    free = Perception().process(frame)
    mapped = Perception().process(frame, mapped_positions=[objects[1].centre])
    assert not any(r.mapped for r in free)
    for a, b in zip(free, mapped, strict=True):
        i = nearest_object(a.position, objects)
        assert b.mapped == (i == 1)
        if i == 1:
            assert b.activation < a.activation
        else:
            assert b.activation == pytest.approx(a.activation)


def test_tactile_response_raises_the_touched_roi_activation() -> None:
    objects = table1_objects("cylinder")
    o = objects[2]
    touch = HapticReading(arm=1, contact=True, position=(o.x - 0.05, o.y, 0.05), weight=1.0)
    plain = Perception().process(make_frame(objects, gaze=CENTRE_GAZE, seed=9))
    felt = Perception().process(make_frame(objects, gaze=CENTRE_GAZE, seed=9, haptic=touch))
    for a, b in zip(plain, felt, strict=True):
        touched = nearest_object(b.position, objects) == 2
        assert b.tactile == (1.0 if touched else 0.0)
        assert (b.activation > a.activation) if touched else (b.activation == a.activation)


def test_visual_motion_flags_a_moved_object_not_the_still_ones() -> None:
    objects = table1_objects("cylinder")
    perception = Perception()
    first = perception.process(make_frame(objects, gaze=CENTRE_GAZE, seed=10))
    assert all(r.motion == 0.0 for r in first)  # no previous frame
    still = perception.process(make_frame(objects, gaze=CENTRE_GAZE, seed=11))
    assert all(r.motion < 0.2 for r in still)
    moved = list(objects)
    moved[3] = dataclasses.replace(objects[3], x=objects[3].x + 0.06)
    after = perception.process(make_frame(moved, gaze=CENTRE_GAZE, seed=12))
    for r in after:
        if nearest_object(r.position, moved) == 3:
            assert r.motion > 0.5
        else:
            assert r.motion < 0.2


def test_activation_is_the_weighted_mean_of_its_terms() -> None:
    objects = [Shape("cylinder", 0.9, 0.0, 0.1, 99.0)]
    frame = make_frame(objects, seed=13)
    only_size = PerceptionConfig(weight_size=1.0, weight_intensity=0.0, weight_motion=0.0,
                                 weight_tactile=0.0, weight_unmapped=0.0, size_norm=0.05)
    r = Perception(only_size).process(frame)[0]
    assert r.activation == pytest.approx(min(1.0, r.retinal_size / 0.05))
    only_intensity = dataclasses.replace(only_size, weight_size=0.0, weight_intensity=2.0)
    r = Perception(only_intensity).process(frame)[0]
    assert r.activation == pytest.approx(r.mean_intensity / only_intensity.contrast_max)
    r = Perception().process(frame)[0]
    assert 0.0 <= r.activation <= 1.0


def test_last_log_reset_and_timings() -> None:
    perception = Perception()
    assert perception.last_log == ([], [])
    objects = table1_objects("sphere", positions=SPREAD)
    touch = HapticReading(arm=0, contact=True, position=objects[0].centre, weight=1.0)
    perception.process(make_frame(objects, gaze=CENTRE_GAZE, haptic=touch))
    left, right = perception.last_log
    assert len(left) == len(right) == 3
    assert all(g.shape == (128, 128) and g.dtype == np.float32 for g in left + right)
    assert len(perception.haptic_memory) == 1
    assert set(perception.last_timings) >= {"log", "segment", "match", "features"}
    perception.reset()
    assert perception.last_log == ([], []) and len(perception.haptic_memory) == 0


def test_a_frame_that_does_not_fit_its_camera_is_rejected() -> None:
    frame = make_frame([], seed=14)
    bad = dataclasses.replace(frame, left=frame.left[:64])
    with pytest.raises(MessageError, match="left"):
        Perception().process(bad)
    nan = frame.right.copy()
    nan[3, 3] = np.nan
    with pytest.raises(MessageError, match="right"):
        Perception().process(dataclasses.replace(frame, right=nan))


# -- segmentation by convexity (segmentation.ground_notches, grouping, roi_finder) ---------

def _disc(shape: tuple[int, int], centre: tuple[int, int], radius: int) -> np.ndarray:
    rr, cc = np.indices(shape)
    return (rr - centre[0]) ** 2 + (cc - centre[1]) ** 2 <= radius ** 2


def test_a_convex_region_holds_no_notch_and_two_overlapping_discs_do() -> None:
    ground = np.ones((40, 60), bool)
    one = _disc(ground.shape, (20, 20), 9)
    assert ground_notches(one, ground & ~one, deeper_than=1.5) == []
    two = one | _disc(ground.shape, (24, 36), 9)
    notches = ground_notches(two, ground & ~two, deeper_than=1.5)
    assert len(notches) == 2  # the corners where the two outlines meet, above and below
    assert all(depth > 1.5 for depth, _ in notches)


def test_a_notch_must_open_onto_the_hull_and_touch_both_parts() -> None:
    ground = np.ones((40, 40), bool)
    square = np.zeros((40, 40), bool)
    square[5:35, 5:35] = True
    holed = square.copy()
    holed[18:22, 18:22] = False  # an enclosed hole (a dark spot) is no notch
    assert ground_notches(holed, ground & ~holed) == []
    left, right = square.copy(), square.copy()
    left[:, 20:] = False
    right[:, :20] = False
    right[5:12, 25:35] = False  # a bite out of the right part, away from the left one
    both = left | right
    assert ground_notches(both, ground & ~both, deeper_than=1.5)
    assert ground_notches(both, ground & ~both, (left, right), deeper_than=1.5) == []


def test_faces_of_one_convex_object_join_and_overlapping_objects_stay_apart() -> None:
    frag = np.zeros((40, 70), np.int32)
    frag[5:20, 5:30] = 1  # the top face of a box
    frag[20:35, 5:30] = 2  # its front face
    disc_a, disc_b = _disc(frag.shape, (20, 45), 9), _disc(frag.shape, (26, 58), 9)
    frag[disc_a] = 3
    frag[disc_b & ~disc_a] = 4  # a second disc partly hidden by the first
    owner = group_fragments(frag, frag == 0, adjacency(frag), min_pixels=12, notch_px=1.5)
    assert owner[1] == owner[2]
    assert owner[3] != owner[4]
    assert owner[2] != owner[3]


def test_two_objects_that_touch_only_through_a_stray_pixel_stay_apart() -> None:
    # two_rows.yaml: a sphere's fragment kept one noise pixel beside a cylinder's outline,
    # so the two fragments "touched" through it; the cheap concavity test looked at the
    # larger part alone, found no notch, and the two objects were one ROI.
    frag = np.zeros((40, 60), np.int32)
    frag[_disc(frag.shape, (20, 18), 10)] = 1
    frag[_disc(frag.shape, (20, 40), 10)] = 2  # one column of ground between the discs
    frag[12, 33] = 1  # the stray pixel, beside disc 2 and far from disc 1
    assert frag[12, 34] == 2 and (frag[11:14, 30:33] == 0).all()
    union = frag > 0
    assert deepest_defect(union) == float("inf")
    assert ground_notches(union, ~union, deeper_than=1.5)
    owner = group_fragments(frag, frag == 0, adjacency(frag), min_pixels=12, notch_px=1.5)
    assert owner[1] != owner[2]


def test_slivers_join_the_neighbour_they_share_most_boundary_with() -> None:
    frag = np.zeros((20, 30), np.int32)
    frag[2:18, 2:14] = 1
    frag[2:18, 16:28] = 2
    frag[5:9, 14] = 3   # 4 px beside fragment 1, 2 of them beside fragment 2 too
    frag[5:7, 15] = 3
    frag[9, 14] = 4     # a sliver that touches only the sliver 3 (and 1)
    frag[1, 5:8] = 5    # a rim sliver on fragment 1
    out = absorb_slivers(frag, min_pixels=12)
    assert set(np.unique(out)) == {0, 1, 2}
    assert out[1, 6] == out[5, 14] == out[9, 14] == 1
    assert (out[frag == 2] == 2).all()


def test_a_fragment_holding_two_objects_of_one_grey_is_cut_at_their_notches() -> None:
    image = np.full((40, 70), 0.02, np.float32)
    two = _disc(image.shape, (20, 24), 10) | _disc(image.shape, (24, 42), 10)
    image[two] = 0.4
    labels = two.astype(np.int32)
    cut = split_at_notches(labels, image, ~two, 0.02, notch_px=1.5, min_pixels=12)
    parts = [int(v) for v in np.unique(cut) if v > 0]
    assert len(parts) == 2
    left, right = (cut == parts[0]), (cut == parts[1])
    assert left[20, 16] != left[24, 50] and right[20, 16] != right[24, 50]


def test_sampled_costs_average_regions_and_windows() -> None:
    rows, cols = np.array([0, 0, 1, 3]), np.array([0, 2, 1, 3])
    costs = np.array([[1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0, 8.0]], np.float32)
    sampled = SampledCosts(rows, cols, costs, (4, 4))
    mask = np.zeros((2, 3), bool)
    mask[0, :] = True
    curve, n = sampled.curve(mask, 0, 0)
    assert n == 2 and np.allclose(curve, [1.5, 0.0])
    means, counts = sampled.window_means(0, (0, 0, 2, 2), 1)
    assert counts[0, 0] == 2 and means[0, 0] == pytest.approx(2.0)  # samples (0,0), (1,1)
    assert counts[1, 1] == 3 and means[1, 1] == pytest.approx(2.0)


def test_a_sphere_before_a_box_of_about_its_grey_gives_two_pure_rois() -> None:
    # The sphere's top hides the bottom of the box's front: a T-junction at each side.
    objects = [Shape("cube", 0.85, 0.0, 0.2, 80.0, yaw=0.3),
               Shape("sphere", 0.62, 0.03, 0.12, 85.0)]
    for seed in (21, 22):
        frame = make_frame(objects, gaze=(0.75, 0.0, 0.05), seed=seed)
        perception = Perception()
        rois = perception.process(frame)
        assert len(rois) == 2
        for roi in rois:
            truth = frame.left_labels[perception.last_roi_labels == roi.roi_id + 1]
            shares = np.bincount(truth[truth >= 0], minlength=2) / truth.size
            assert shares.max() >= 0.85 and shares.min() < 0.15, (seed, shares)
        near = min(rois, key=lambda r: r.position[0])
        assert np.hypot(near.position[0] - 0.62, near.position[1] - 0.03) < 0.03


def test_batched_visual_motion_equals_the_motion_of_each_roi_alone() -> None:
    cfg = PerceptionConfig()
    objects = table1_objects("cylinder")
    moved = list(objects)
    moved[1] = dataclasses.replace(objects[1], x=objects[1].x + 0.05)
    before = make_frame(objects, gaze=CENTRE_GAZE, seed=15)
    after = make_frame(moved, gaze=(0.9, 0.06, 0.04), seed=16)  # the eyes moved too
    previous = MotionView(motion_image(before.left, cfg), before.camera, before.left_pose)
    image = motion_image(after.left, cfg)
    rois = []
    for i in range(len(moved)):
        rr, cc = np.nonzero(after.left_labels == i)
        bbox = (int(cc.min()), int(rr.min()), int(cc.max()) + 1, int(rr.max()) + 1)
        mask = after.left_labels[bbox[1]:bbox[3], bbox[0]:bbox[2]] == i
        rois.append((mask, bbox, float(np.linalg.norm(np.asarray(moved[i].centre)
                                                      - after.left_pose.position))))
    thin = np.ones((1, 6), bool)  # too thin to erode
    rois += [(thin, (60, 5, 66, 6), 1.0), (rois[0][0], rois[0][1], float("nan")),
             (rois[2][0], rois[2][1], 0.05)]  # no depth; re-projected out of view
    alone = [visual_motion(image, m, b, d, after.camera, after.left_pose, previous, cfg)
             for m, b, d in rois]
    batched = visual_motion_batch(image, rois, after.camera, after.left_pose, previous, cfg)
    assert batched == alone
    assert alone[1] > 0.3 and alone[-2] == 0.0  # the moved object; the one without depth
    assert visual_motion_batch(image, rois, after.camera, after.left_pose, None, cfg) == [
        0.0] * len(rois)
    assert visual_motion_batch(image, [], after.camera, after.left_pose, previous, cfg) == []


def test_a_region_curve_depends_only_on_its_own_pixels() -> None:
    # find_objects recomputes the curves of poorly supported objects from their pixels
    # alone; that must give the columns a run over every pixel gives.
    rng = np.random.default_rng(17)
    costs = rng.random((40, 3000), dtype=np.float32)
    labels = rng.integers(0, 9, 3000)
    everything, support = region_curves(costs, labels, np.ones(3000), 8)
    assert support.sum() == 3000
    some = np.isin(labels, [2, 5, 8])
    alone, _ = region_curves(costs[:, some], labels[some], np.ones(int(some.sum())), 8)
    assert np.array_equal(alone[:, [2, 5, 8]], everything[:, [2, 5, 8]])
    assert not alone[:, [1, 3]].any()


def test_the_ground_median_is_numpy_median() -> None:
    rng = np.random.default_rng(18)
    for n in (1, 2, 3, 10, 501, 3000):
        values = rng.random(n).astype(np.float32)
        ties = np.round(values * 5).astype(np.float32) / 7  # many equal values
        for v in (values, ties):
            got, want = _median(v), np.median(v)
            assert got == want and got.dtype == want.dtype


def test_an_object_nearly_as_dark_as_the_ground_gets_its_own_roi() -> None:
    """worlds/dark_bright.yaml: a grey-25 prism touching a grey-240 box. Every prism pixel
    lies under fg_threshold; the dim foreground (segmentation.dim_foreground, from the
    ground's own noise) finds it, and it becomes a ROI of its own at its place, apart from
    the box. On a world of ordinary greys the dim foreground is empty."""
    from pathlib import Path

    from roger_common.types import Action, Goal
    from roger_perception.segmentation import dim_foreground, foreground_mask
    from roger_sim.simulator import Simulator
    from roger_sim.world import load_world

    worlds = Path(__file__).resolve().parent.parent / "worlds"
    with Simulator(load_world(worlds / "dark_bright.yaml")) as sim:
        _, frame = sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, (0.62, 0.0, 0.05)))
    names = list(frame.label_names)
    prism = frame.left_labels == names.index("dark_prism")
    box = frame.left_labels == names.index("bright_box")
    cfg = PerceptionConfig()
    without = PerceptionConfig(dim_sigmas=0.0)
    fg, _ = foreground_mask(frame.left, without)
    assert prism.sum() > 100 and fg[prism].mean() < 0.05   # under the bright threshold
    dim = dim_foreground(frame.left, fg, cfg).astype(bool)
    assert prism[dim].mean() > 0.9 and dim[prism].mean() > 0.6
    for config, found in ((without, False), (cfg, True)):
        rois = Perception(config).process(frame)
        mostly_prism = []
        for r in rois:
            u0, v0, u1, v1 = r.bbox
            inside = frame.left_labels[v0:v1, u0:u1]
            if np.mean(inside == names.index("dark_prism")) > 0.5:
                mostly_prism.append(r)
            if np.mean(inside == names.index("bright_box")) > 0.5:
                assert np.mean(inside == names.index("dark_prism")) < 0.1
        assert bool(mostly_prism) is found, config.dim_sigmas
    assert len(mostly_prism) == 1
    assert np.linalg.norm(np.asarray(mostly_prism[0].position[:2]) - (0.62, 0.09)) < 0.03
    assert box.sum() > 100
    with Simulator(load_world(worlds / "inspection.yaml")) as sim:
        for target in ((0.6, 0.0, 0.05), (0.45, 0.35, 0.05), (0.5, -0.4, 0.05)):
            _, frame = sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, target))
            fg, _ = foreground_mask(frame.left, without)
            assert not dim_foreground(frame.left, fg, cfg).any(), target


def test_window_boxes_keep_the_object_and_drop_the_seam() -> None:
    from roger_perception.segmentation import window_boxes

    rng = np.random.default_rng(5)
    image = 0.039 + 0.01 * rng.standard_normal((64, 64)).astype(np.float32)  # the ground
    labels = np.zeros((64, 64), np.int32)
    # 1: a bright object (rows 10-17, cols 10-17) whose ROI also holds a rim and an 8 px
    # seam of ground two rows below it.
    image[10:18, 10:18] += 0.3
    labels[9:19, 9:19] = 1
    labels[20, 4:18] = 1
    # 2: an object as dark as grey 25 (0.02 above the ground: 2 of its pixel noise).
    image[30:42, 30:42] += 0.022
    labels[29:43, 29:43] = 2
    # 3: a ROI cut by the retina's left edge, with a rim column on its right.
    image[50:60, 0:6] += 0.3
    labels[50:60, 0:7] = 3
    # 4: a ROI of ground only keeps its box.
    labels[2:5, 40:50] = 4
    boxes = [(4, 9, 19, 21), (29, 29, 43, 43), (0, 50, 7, 60), (40, 2, 50, 5)]
    got = window_boxes(image, labels, boxes, 3.0)
    assert got[0] == (10, 10, 18, 18)
    assert abs(got[1][0] - 30) <= 1 and abs(got[1][1] - 30) <= 1
    assert abs(got[1][2] - 42) <= 1 and abs(got[1][3] - 42) <= 1
    assert got[2] == (0, 50, 6, 60)
    assert got[3] == boxes[3]
    assert window_boxes(image, labels, boxes, 0.0) == boxes

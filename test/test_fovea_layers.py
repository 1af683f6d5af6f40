"""An object in line behind the fixated one, parted from it by the two foveae's disparity
(roger_perception/fovea_layers.py, docs/perception.md "An object in line behind, parted in
the fovea")."""

from __future__ import annotations

import numpy as np
import pytest

from roger_common.conversions import stereo_geometry_msg
from roger_common.types import Action, CameraModel, EyePose, Goal, ObjectSpec, WorldSpec
from roger_experiments.evaluation import object_under_window
from roger_perception.config import PerceptionConfig
from roger_perception.fovea_layers import (
    Layer,
    Layers,
    fixated_layers,
    layer_behind,
    project_layer,
)
from roger_perception.perception import (
    Perception,
    _faces,
    _occluder_beside,
    grown_across_greys,
)
from roger_perception.perception_node import _complete
from roger_perception.roi_finder import find_objects
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator

#: A 0.08 m prism standing 15 cm behind a 0.10 m cylinder, within 2 degrees of its bearing
#: from the eyes: the retinas see one object (a random world's pair that the closed loop
#: never visited).
NEAR = ObjectSpec("near", "cylinder", (0.703, -0.477), 0.10, 65.0, 0.8, yaw=1.57)
FAR = ObjectSpec("far", "prism", (0.824, -0.563), 0.08, 109.0, 0.4)
PAIR = WorldSpec((NEAR, FAR))
#: A 0.14 m box 19 cm in front of a 0.09 m cylinder: fixating the cylinder, the box's edge
#: joins the cylinder's ROI (a random world's pair whose cylinder window the scorer read as
#: empty, and whose look was stored as an object of nothing).
EDGE = ObjectSpec("near", "box", (0.351, -0.693), 0.14, 104.0, 1.6, yaw=0.23)
BEHIND_EDGE = ObjectSpec("far", "cylinder", (0.322, -0.883), 0.09, 68.0, 0.2, yaw=2.33)
#: A dark 0.10 m box 16 cm in front of a darker 0.09 m prism: fixating the box, the prism
#: and the top of the box form one ROI and the box's front face another; the box's top
#: (grey 50 in the retina) and its front face (35, the prism's grey) both meet the first
#: (a random world's pair that the closed loop never visited).
DARK_BOX = ObjectSpec("near", "box", (0.789, 0.415), 0.10, 60.0, 1.5, yaw=0.32)
DARK_PRISM = ObjectSpec("far", "prism", (0.917, 0.516), 0.09, 51.0, 0.8, yaw=0.34)
#: A 0.10 m box turned about 20 degrees from the eye with a 0.08 m cylinder 16 cm behind
#: it, under a degree apart in bearing: the box's lit top and the cylinder render alike, so
#: both retinas see one object, and in the fovea the cylinder holds more of the samples
#: than the box (a random world's pair, 10124, whose cylinder the closed loop never
#: visited).
SAME_GREY_BOX = ObjectSpec("near", "box", (0.618, -0.551), 0.10, 58.0, 0.8, yaw=2.76)
SAME_GREY_CYLINDER = ObjectSpec("far", "cylinder", (0.747, -0.648), 0.08, 93.0, 0.6,
                                yaw=1.76)


def _look(world: WorldSpec, at: tuple[float, float], seed: int = 0,
          config: SimConfig | None = None):
    """A shift to ``at`` and a visual improvement there: the improvement's frame."""
    with Simulator(world, config or SimConfig(), seed=seed) as sim:
        target = (at[0], at[1], 0.05)
        sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, target))
        return sim.run_goal(Goal(2, Action.VISUAL_IMPROVEMENT, target))[1]


def _fixated_layer(frame):
    seen, _ = find_objects(frame, PerceptionConfig())
    from roger_perception.fovea import fixated
    (obj,) = [o for o in seen if fixated(o.blob.mask, o.blob.bbox, frame.camera)]
    layer = layer_behind(frame.fovea, frame.fovea_right, frame.fovea_camera, frame.camera,
                         frame.left_pose, frame.right_pose, obj.blob.mask, obj.blob.bbox,
                         obj.depth, obj.width_px * obj.depth / frame.camera.focal_px, 12)
    return obj, layer


def _names(frame, obj, mask) -> dict[str, int]:
    u0, v0, u1, v1 = obj.blob.bbox
    labels = frame.left_labels[v0:v1, u0:u1][mask]
    return {frame.label_names[i]: int((labels == i).sum()) for i in set(labels.tolist())
            if i >= 0}


def _windows_by_mode(frame) -> dict[str, list[str | None]]:
    """The object under each attention window perception gives ``frame``, per mode."""
    shown = {}
    for mode in ("extended", "paper"):
        rois = Perception(PerceptionConfig(features=mode)).process(frame)
        shown[mode] = [object_under_window(frame.left_labels, frame.label_names, r.bbox)
                       for r in rois]
    return shown


def test_the_simulator_renders_the_right_fovea_with_its_own_noise() -> None:
    on = _look(PAIR, NEAR.position)
    off = _look(PAIR, NEAR.position, config=SimConfig(fovea_stereo=False))
    assert on.fovea_right is not None and off.fovea_right is None
    assert on.fovea_right.shape == on.fovea.shape
    # The left fovea and the retinas are the same with or without the right fovea.
    assert np.array_equal(on.fovea, off.fovea) and np.array_equal(on.left, off.left)
    assert not np.array_equal(on.fovea_right, on.fovea)
    msg = stereo_geometry_msg(on)
    assert msg.fovea and msg.fovea_right
    assert not stereo_geometry_msg(off).fovea_right


def test_perception_waits_for_the_right_fovea_only_when_the_pair_says_it_has_one() -> None:
    frame = _look(PAIR, NEAR.position)
    geometry = stereo_geometry_msg(frame)
    parts = {"left": 0, "right": 0, "info": 0, "fovea": 0, "fovea_info": 0,
             "geometry": geometry}
    assert not _complete(parts)
    assert _complete({**parts, "fovea_right": 0})
    geometry.fovea_right = False
    assert _complete(parts)


@pytest.mark.parametrize("fixate", [NEAR, FAR])
def test_the_layer_behind_is_the_far_objects_top(fixate: ObjectSpec) -> None:
    frame = _look(PAIR, fixate.position)
    obj, layer = _fixated_layer(frame)
    assert {"near", "far"} <= _names(frame, obj, obj.blob.mask).keys()  # one ROI for both
    assert layer is not None
    names = _names(frame, obj, layer.mask)
    # Most of the layer is the far object's, and most of the far object's pixels are in it.
    assert names.get("far", 0) >= 2 * names.get("near", 0)
    assert names["far"] >= 0.5 * _names(frame, obj, obj.blob.mask)["far"]
    assert layer.depth > obj.depth + 0.05
    # Its points stand above the ground, around the far object's place.
    centre = np.median(layer.points, axis=0)
    assert np.hypot(centre[0] - FAR.position[0], centre[1] - FAR.position[1]) < 0.08
    assert (layer.points[:, 2] > 0.02).all()


@pytest.mark.parametrize("spec", [
    ObjectSpec("box45", "box", (0.62, -0.2), 0.2, 110.0, 1.0, yaw=0.785),
    ObjectSpec("box_near", "box", (0.82, 0.0), 0.2, 110.0, 1.0),
    ObjectSpec("checker", "box", (0.613, -0.514), 0.2, 110.0, 1.0, yaw=-0.3,
               texture="checker"),
    ObjectSpec("sphere", "sphere", (0.7, 0.3), 0.16, 70.0, 0.8),
    ObjectSpec("prism", "prism", (0.75, -0.35), 0.2, 60.0, 0.6, yaw=0.4),
])
def test_an_object_alone_has_no_layer_behind(spec: ObjectSpec) -> None:
    """Its own far side (a box turned to the eye, a big box near it, a periodic texture)
    and the ground just beyond its top edge are not another object."""
    frame = _look(WorldSpec((spec,)), spec.position)
    obj, layer = _fixated_layer(frame)
    assert layer is None
    # Nor a layer in front: its own front face or near edge is within its footprint.
    assert fixated_layers(frame.fovea, frame.fovea_right, frame.fovea_camera, frame.camera,
                          frame.left_pose, frame.right_pose, obj.blob.mask, obj.blob.bbox,
                          obj.depth, obj.width_px * obj.depth / frame.camera.focal_px, 12,
                          position=obj.position) == (None, None)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_nearer_objects_edge_in_the_fixated_roi_is_a_layer_in_front(seed: int) -> None:
    """Fixating the far cylinder, the box's edge that joined its ROI is found in front, at
    the box's place, beside the box's own ROI; perception takes it out of the ROI."""
    world = WorldSpec((EDGE, BEHIND_EDGE))
    frame = _look(world, BEHIND_EDGE.position, seed=seed)
    seen, _ = find_objects(frame, PerceptionConfig())
    from roger_perception.fovea import fixated
    (obj,) = [o for o in seen if fixated(o.blob.mask, o.blob.bbox, frame.camera)
              and _names(frame, o, o.blob.mask).get("far", 0) > 20]
    joined = _names(frame, obj, obj.blob.mask)
    assert joined.get("near", 0) >= 5                      # the box's edge joined it
    behind, front = fixated_layers(
        frame.fovea, frame.fovea_right, frame.fovea_camera, frame.camera, frame.left_pose,
        frame.right_pose, obj.blob.mask, obj.blob.bbox, obj.depth,
        obj.width_px * obj.depth / frame.camera.focal_px, 12, position=obj.position)
    assert behind is None and front is not None and front.front
    assert front.depth < obj.depth - 0.1
    centre = np.median(front.points, axis=0)
    assert np.hypot(centre[0] - EDGE.position[0], centre[1] - EDGE.position[1]) < 0.1
    assert _occluder_beside(front, obj, seen, frame.camera)
    # Without its position (the paper's test of behind alone) none is looked for.
    assert fixated_layers(frame.fovea, frame.fovea_right, frame.fovea_camera, frame.camera,
                          frame.left_pose, frame.right_pose, obj.blob.mask, obj.blob.bbox,
                          obj.depth, obj.width_px * obj.depth / frame.camera.focal_px,
                          12)[1] is None
    # Perception (extended) takes the edge out of the cylinder's ROI; the paper mode keeps
    # it: the box's pixels among the ROI's own.
    near_in = {}
    for mode in ("extended", "paper"):
        perception = Perception(PerceptionConfig(features=mode))
        rois = perception.process(frame)
        (roi,) = [r for r in rois if np.hypot(r.position[0] - BEHIND_EDGE.position[0],
                                              r.position[1] - BEHIND_EDGE.position[1]) < 0.06]
        own = perception.last_roi_labels == roi.roi_id + 1
        near_in[mode] = int((frame.left_labels[own] == frame.label_names.index("near")).sum())
    assert near_in["paper"] >= 5 and near_in["extended"] <= near_in["paper"] // 2, near_in


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_top_of_a_box_whose_front_face_has_the_far_objects_grey_leaves_its_roi(
        seed: int) -> None:
    """Fixating the dark box, its top (joined to the prism behind it) is taken out of the
    prism's ROI by the face of the box it continues, not by the front face whose grey is
    the prism's: the prism gets a window of its own in the extended mode; in the paper mode
    no window shows it."""
    frame = _look(WorldSpec((DARK_BOX, DARK_PRISM)), DARK_BOX.position, seed=seed)
    shown = _windows_by_mode(frame)
    assert "far" in shown["extended"] and "far" not in shown["paper"], shown


@pytest.mark.parametrize(("at", "seed"), [((0.618, -0.551), 0), ((0.747, -0.648), 1)])
def test_a_far_object_holding_most_of_the_samples_is_still_the_layer_behind(
        at: tuple[float, float], seed: int) -> None:
    """The most samples of the pair's ROI are the cylinder's, so the surface they hold was
    taken for the fixated one and the box found no place beyond it. The samples fall
    apart into two groups by disparity, the farther one beyond the nearer one's front
    plus an object's depth: the farther one is the layer behind, and the cylinder gets a
    window of its own (the paper mode, which never parts a ROI, shows none)."""
    frame = _look(WorldSpec((SAME_GREY_BOX, SAME_GREY_CYLINDER)), at, seed=seed)
    obj, layer = _fixated_layer(frame)
    joined = _names(frame, obj, obj.blob.mask)
    assert joined.get("near", 0) > 100 and joined.get("far", 0) > 30     # one ROI for both
    assert layer is not None
    names = _names(frame, obj, layer.mask)
    assert names.get("far", 0) >= 2 * names.get("near", 0)
    assert names["far"] >= 0.5 * joined["far"]
    centre = np.median(layer.points, axis=0)
    assert np.hypot(centre[0] - SAME_GREY_CYLINDER.position[0],
                    centre[1] - SAME_GREY_CYLINDER.position[1]) < 0.08
    shown = _windows_by_mode(frame)
    assert "far" in shown["extended"] and "far" not in shown["paper"], shown


def test_a_growth_across_greys_stops_at_a_step_and_is_refused_where_it_drifts() -> None:
    grey = np.full((6, 8), 0.20, np.float32)
    grey[:, 4:] = 0.30                                  # two surfaces, 2.3 steps apart
    mask = np.ones(grey.shape, bool)
    start = np.zeros(grey.shape, bool)
    start[2, 1] = True
    grown = grown_across_greys(start, mask, grey, step=0.044, reference=0.20)
    assert grown is not None and grown[:, :4].all() and not grown[:, 4:].any()
    # One grey shaded across both (a ramp of a fifth of a step per column): the growth
    # stops by drifting two steps from its reference, not at a step, and is refused.
    ramp = (0.20 + 0.009 * np.arange(16, dtype=np.float32))[None, :].repeat(6, axis=0)
    start = np.zeros(ramp.shape, bool)
    start[2, 0] = True
    assert grown_across_greys(start, np.ones(ramp.shape, bool), ramp, 0.044, 0.20) is None
    # Everything grown (nothing left to tell it from) is refused; an edge with no pair
    # within the mask (ground between the two) is not.
    one = np.zeros(grey.shape, bool)
    one[2, 1] = True
    assert grown_across_greys(one, mask, np.full(grey.shape, 0.2, np.float32), 0.044,
                              0.2) is None
    island = np.zeros(grey.shape, bool)
    island[1:3, 1:3] = True
    rest = np.zeros(grey.shape, bool)
    rest[4:, 5:] = True
    assert grown_across_greys(island, island | rest, grey, 0.044, 0.20) is not None


def test_an_occluders_faces_are_two_greys_a_step_apart_each_a_quarter_of_its_pixels() -> None:
    rng = np.random.default_rng(0)
    top, front = 0.20 + 0.005 * rng.standard_normal(14), 0.14 + 0.005 * rng.standard_normal(16)
    faces = _faces(np.concatenate([top, front]), step=0.044)
    assert len(faces) == 2 and abs(faces[0] - 0.14) < 0.01 and abs(faces[1] - 0.20) < 0.01
    # A stray pixel of another grey is no face; nor are two greys less than a step apart.
    assert len(_faces(np.concatenate([top, [0.05, 0.06]]), step=0.044)) == 1
    assert len(_faces(np.concatenate([top, top + 0.03]), step=0.044)) == 1


def test_the_far_object_gets_a_roi_and_a_window_of_its_own_in_later_frames_too() -> None:
    """Extended mode: the fixated ROI is parted on the look with both foveae, and the kept
    layer parts it again in a later frame from another view (no fovea); the paper mode
    never parts it."""
    cfg = SimConfig()
    for mode, parted in (("extended", True), ("paper", False)):
        perception = Perception(PerceptionConfig(features=mode))
        with Simulator(PAIR, cfg, seed=1) as sim:
            target = (NEAR.position[0], NEAR.position[1], 0.05)
            sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, target))
            _, look = sim.run_goal(Goal(2, Action.VISUAL_IMPROVEMENT, target))
            rois = perception.process(look)
            _, later = sim.run_goal(Goal(3, Action.ATTENTION_SHIFT,
                                         (FAR.position[0], FAR.position[1], 0.05)))
            rois_later = perception.process(later)
        for frame, found in ((look, rois), (later, rois_later)):
            shown = [object_under_window(frame.left_labels, frame.label_names, r.bbox)
                     for r in found]
            assert ("far" in shown) is parted, (mode, shown)
            assert "near" in shown or not parted
        if parted:
            (far,) = [r for r in rois_later if object_under_window(
                later.left_labels, later.label_names, r.bbox) == "far"]
            assert np.hypot(far.position[0] - FAR.position[0],
                            far.position[1] - FAR.position[1]) < 0.08


def test_layers_are_kept_by_position_and_forgotten_by_a_look_that_finds_none() -> None:
    layers = Layers(radius=0.08)
    layer = Layer(mask=np.ones((2, 2), bool), points=np.zeros((1, 3)), depth=1.0, samples=30)
    layers.put((0.5, 0.2, 0.05), layer)
    assert layers.near((0.52, 0.21, 0.0)) == [layer] and layers.near((0.7, 0.2, 0.0)) == []
    layers.put((0.51, 0.2, 0.05), layer)  # the same ROI: replaced, not added
    assert len(layers) == 1
    layers.put((0.5, 0.19, 0.05), None)
    assert len(layers) == 0


def test_a_kept_layer_falls_on_the_pixels_its_points_project_to() -> None:
    camera = CameraModel(width=64, height=64, focal_px=50.0)
    pose = EyePose(position=np.zeros(3), rotation=np.eye(3))
    mask = np.ones((20, 20), bool)
    # Points 1 m ahead covering pixels (u, v) 30..34 x 20..23 of the image.
    us, vs = np.meshgrid(np.arange(30, 35) + 0.5, np.arange(20, 24) + 0.5)
    pts = np.stack([(us.ravel() - 32) / 50.0, (vs.ravel() - 32) / 50.0,
                    np.ones(us.size)], axis=1)
    far = project_layer(pts, camera, pose, mask, (20, 15, 40, 35), 12)
    assert far is not None
    rows, cols = np.nonzero(far)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (5, 8, 10, 14)
    # Too few pixels, or none left to the nearer object: no layer.
    assert project_layer(pts[:3], camera, pose, mask, (20, 15, 40, 35), 12) is None
    assert project_layer(pts, camera, pose, np.ones((4, 5), bool), (30, 20, 35, 24),
                         12) is None

"""An object in line behind a taller one, seen only above it: the cap the plane sweep cuts
off by its depth (roger_perception/behind.py, docs/perception.md "An object behind, seen
above another")."""

from __future__ import annotations

import numpy as np

from roger_common.types import Action, Goal, ObjectSpec, WorldSpec
from roger_experiments.evaluation import object_under_window
from roger_perception.behind import MAX_SHARE, along_rows, cap_behind, window_best_planes
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_perception.plane_sweep import SampledCosts
from roger_sim.simulator import Simulator

#: Eleven hypotheses, 1/m: 0.4 (index 0, 2.5 m) to 2.4 (index 10, 0.42 m).
INVERSE = np.linspace(0.4, 2.4, 11)
NEAR, FAR = 8, 1  # the object's own hypothesis and one far behind it


def _scene(cap_rows: int, cap_plane: int, shape: tuple[int, int] = (20, 12), start: int = 0
           ) -> tuple[np.ndarray, SampledCosts, np.ndarray]:
    """An object filling a 20 x 12 retina, every pixel sampled: ``cap_rows`` rows from row
    ``start`` match best at ``cap_plane``, the rest at NEAR (cost 0.01 there, 0.01 + 0.01
    per hypothesis away). Returns (mask, sampled costs, every pixel's costs (J, H, W))."""
    h, w = shape
    best = np.full((h, w), NEAR)
    best[start:start + cap_rows] = cap_plane
    planes = np.arange(INVERSE.size)[:, None, None]
    costs = (0.01 + 0.01 * np.abs(planes - best[None])).astype(np.float32)
    rows, cols = np.indices((h, w))
    sampled = SampledCosts(rows.ravel(), cols.ravel(), costs.reshape(INVERSE.size, -1), (h, w))
    return np.ones((h, w), bool), sampled, costs


def _costs_of(costs: np.ndarray):
    return lambda r, c: costs[:, r, c]


def _cap(mask, sampled, costs, bound=1.2, textured=None, min_pixels=12):
    textured = np.ones(mask.shape, bool) if textured is None else textured
    return cap_behind(mask, (0, 0), bound, sampled, _costs_of(costs), INVERSE, textured,
                      min_pixels, 8, 3.0)


def test_window_best_planes_reads_each_pixels_window_and_only_the_samples_asked() -> None:
    mask, sampled, _ = _scene(4, FAR)
    best, counts = window_best_planes(sampled, (0, 0, 20, 12))
    assert (best[:3] == FAR).all() and (best[5:] == NEAR).all()
    assert counts[10, 5] == 9 and counts[0, 0] == 4
    use = np.zeros((20, 12), bool)
    use[10:] = True
    best, counts = window_best_planes(sampled, (0, 0, 20, 12), use)
    assert (best[:9] == -1).all() and (counts[:9] == 0).all()
    assert (best[10:] == NEAR).all()


def test_along_rows_marks_edges_across_the_rows_not_along_them() -> None:
    image = np.zeros((20, 20), np.float32)
    image[:, 10:] = 0.5  # a vertical edge: a horizontal disparity can be measured there
    marked = along_rows(image, 0.012)
    assert marked[:, 9:11].all() and not marked[:, :7].any() and not marked[:, 13:].any()
    assert not along_rows(image.T.copy(), 0.012).any()  # a horizontal edge tells none


def test_a_top_matching_far_behind_the_object_is_cut_off_with_its_boundary_row_left() -> None:
    mask, sampled, costs = _scene(4, FAR)
    cap = _cap(mask, sampled, costs)
    assert cap is not None
    # Rows 0-3 match far; the row of windows that straddle the boundary (row 3, whose
    # window reaches row 4) goes to the nearer object.
    assert cap[:3].all() and not cap[3:].any()


def test_no_cap_where_the_top_lies_within_the_objects_own_depth() -> None:
    # The top at hypothesis 6 (0.56 m): within the bound of 1.2 m, as a box's far top edge is.
    mask, sampled, costs = _scene(4, 6)
    assert _cap(mask, sampled, costs) is None
    # One hypothesis beyond the bound is the sweep's resolution, not yet an object behind.
    mask, sampled, costs = _scene(4, 2)  # 1.25 m: beyond 1.2 m, within one step (1.54 m)
    assert _cap(mask, sampled, costs) is None


def test_no_cap_from_flat_pixels_whose_depth_the_rows_do_not_tell() -> None:
    mask, sampled, costs = _scene(4, FAR)
    assert _cap(mask, sampled, costs, textured=np.zeros(mask.shape, bool)) is None


def test_no_cap_too_small_above_its_boundary_row() -> None:
    # Two far rows: the second straddles the boundary, one row of 12 px is left, and the
    # cap must hold a ROI's 12 px above its own lowest row. Three: rows 0 and 1 are left.
    mask, sampled, costs = _scene(2, FAR)
    assert _cap(mask, sampled, costs) is None
    mask, sampled, costs = _scene(3, FAR)
    cap = _cap(mask, sampled, costs)
    assert cap is not None and cap[:2].all() and not cap[2:].any()


def test_a_cap_holds_at_most_a_quarter_of_its_object() -> None:
    mask, sampled, costs = _scene(9, FAR)
    cap = _cap(mask, sampled, costs)
    assert cap is not None and cap.sum() <= MAX_SHARE * mask.sum()


def test_no_cap_that_does_not_reach_the_silhouettes_top() -> None:
    # Rows 2-5 match far but rows 0-1 above them do not: no object shows above this one.
    mask, sampled, costs = _scene(4, FAR, start=2)
    assert _cap(mask, sampled, costs) is None
    mask[:2] = False  # the same rows at the silhouette's top are a cap
    assert _cap(mask, sampled, costs) is not None


def test_an_object_behind_a_taller_one_shows_above_it_as_a_roi_of_its_own() -> None:
    # Random 10046's prism c06_1 (grey 118, 0.11 m) stands 0.2 m straight behind the
    # 0.14 m cylinder c02_2 (grey 67): lit, its top reads about the cylinder's grey and the
    # left retina's watershed and grouping join the few rows that show above the cylinder
    # to it. Fixated (the place the robot's map holds for it), without the cut the window
    # of no ROI shows the prism; with it, most shifts onto it do.
    objects = (ObjectSpec("front", "cylinder", (0.749, -0.246), 0.14, 67.0, 1.0, yaw=0.32),
               ObjectSpec("behind", "prism", (0.931, -0.336), 0.11, 118.0, 1.0, yaw=1.26))
    frames = []
    for seed in range(4):
        with Simulator(WorldSpec(objects), seed=seed) as sim:
            frames.append(sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, (0.91, -0.33, 0.08)))[1])
    for split, wanted in ((False, 0), (True, 3)):
        perception = Perception(PerceptionConfig(behind_split=split))
        shown = []
        for frame in frames:
            rois = perception.process(frame)
            shown.append({object_under_window(frame.left_labels, frame.label_names, r.bbox)
                          for r in rois})
        assert all("front" in s for s in shown), shown
        assert sum("behind" in s for s in shown) == wanted, (split, shown)

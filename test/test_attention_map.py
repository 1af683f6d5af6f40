"""The pre-attentional (spatial) map: association, interest, moved / vanished / new objects,
and the winner-take-all of the attention shift.

(That the core imports without ROS is checked elsewhere.)
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roger_attention.config import SpatialMapConfig
from roger_attention.spatial_map import SpatialMap
from roger_common.errors import ConfigError
from roger_common.types import FEATURE_DIM, WEIGHT_INDEX, Roi

#: Every ROI settles at once (settle_observations=1): the tests of association, interest
#: and winner-take-all; the settling itself is tested with the defaults further down.
CFG = SpatialMapConfig(association_radius=0.1, moved_threshold=0.04, vanish_frames=2,
                       interest_rate=0.5, settle_observations=1)


def roi(x: float, y: float, activation: float = 0.5, value: float = 0.3,
        weight: float | None = None) -> Roi:
    features = np.full(FEATURE_DIM, value, np.float32)
    known = np.ones(FEATURE_DIM, bool)
    if weight is None:
        features[WEIGHT_INDEX], known[WEIGHT_INDEX] = 0.0, False
    else:
        features[WEIGHT_INDEX] = weight
    return Roi(roi_id=0, bbox=(0, 0, 4, 4), position=(x, y, 0.05), features=features,
               known=known, activation=activation)


def test_new_rois_settle_with_zero_interest_that_grows_with_time() -> None:
    m = SpatialMap(CFG)
    ch = m.update([roi(0.5, 0.0), roi(0.5, 0.3)], now=0.0)
    assert len(ch.new) == 2 and len(m) == 2
    assert all(e.interest == 0.0 and not e.mapped and e.address == -1 for e in m)
    m.update([roi(0.5, 0.0), roi(0.5, 0.3)], now=2.0)
    assert [e.interest for e in m] == pytest.approx([1.0, 1.0])    # 0.5 /s * 2 s
    m.update([roi(0.5, 0.0), roi(0.5, 0.3), roi(0.9, 0.0)], now=3.0)
    assert [e.interest for e in m] == pytest.approx([1.5, 1.5, 0.0])
    m.advance(2.0)                                                # never backwards
    assert [e.interest for e in m] == pytest.approx([1.5, 1.5, 0.0])


def test_interest_resets_on_focus_and_stays_zero_while_focused() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0), roi(0.5, 0.3)], now=0.0)
    first, second = (e.entry_id for e in m)
    m.advance(4.0)
    m.focus(first, now=4.0)
    assert m.get(first).interest == 0.0 and m.get(second).interest == pytest.approx(2.0)
    m.keep_focus(first, now=5.0)
    assert m.get(first).interest == 0.0 and m.get(second).interest == pytest.approx(2.5)
    m.advance(7.0)
    assert m.get(first).interest == pytest.approx(1.0)


def test_association_by_position_within_radius() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0), roi(0.5, 0.3)], now=0.0)
    ids = [e.entry_id for e in m]
    ch = m.update([roi(0.52, 0.31, activation=0.9), roi(0.49, 0.01)], now=1.0)
    assert ch.new == () and set(ch.associated) == set(ids)
    assert m.get(ids[1]).position == pytest.approx((0.52, 0.31, 0.05))
    assert m.get(ids[1]).activation == pytest.approx(0.9)
    assert m.get(ids[1]).last_seen == 1.0
    ch = m.update([roi(0.8, 0.0)], now=2.0)                       # beyond the radius
    assert len(ch.new) == 1 and len(m) == 3


def test_moved_mapped_entry_loses_its_mapping_status() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0)], now=0.0)
    (eid,) = [e.entry_id for e in m]
    m.set_mapped(eid, address=7)
    assert m.mapped_positions() == [pytest.approx((0.5, 0.0, 0.05))]
    assert m.update([roi(0.52, 0.0)], now=1.0).moved == ()       # jitter below threshold
    assert m.get(eid).mapped and m.get(eid).roi.mapped
    ch = m.update([roi(0.57, 0.0)], now=2.0)                       # 7 cm from where mapped
    assert ch.moved == (eid,) and not m.get(eid).mapped and not m.get(eid).roi.mapped
    assert m.get(eid).address == 7 and m.mapped_positions() == []


def test_vanished_only_when_visible_and_missed_repeatedly() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0), roi(0.5, 0.3)], now=0.0)
    a, b = (e.entry_id for e in m)
    for t in range(1, 5):
        m.update([roi(0.5, 0.3)], now=float(t))                   # no visibility given
    assert a in m
    m.update([roi(0.5, 0.3)], now=5.0, visible=lambda p: False)   # out of view
    assert a in m
    ch = m.update([roi(0.5, 0.3)], now=6.0, visible=lambda p: True)
    assert ch.vanished == () and a in m                            # 1 miss of 2
    ch = m.update([roi(0.5, 0.3)], now=7.0, visible=lambda p: True)
    assert ch.vanished == (a,) and a not in m and b in m
    assert m.get(a) is None


def test_winner_take_all_then_largest_interest() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0, 0.2), roi(0.5, 0.3, 0.9), roi(0.5, 0.6, 0.5)], now=0.0)
    a, b, c = (e.entry_id for e in m)
    assert m.select_focus() == b                                   # largest activation
    assert m.select_focus(exclude=b) == c
    m.set_mapped(b, 1)
    assert m.select_focus() == c                                   # unmapped first
    m.set_mapped(a, 2)
    m.set_mapped(c, 3)
    assert m.all_mapped()
    m.focus(a, now=1.0)
    m.focus(c, now=3.0)
    m.advance(4.0)                                                 # interests a 1.5, b 2, c .5
    assert m.select_focus() == b
    assert m.select_focus(exclude=b) == a
    m.focus(b, now=4.0)                                            # b 0 now
    assert m.select_focus(exclude=a) == c


def test_unmapped_entries_are_each_visited_once_then_in_turn_by_interest() -> None:
    """A policy that shifts without mapping (a Q-learner early on) visits every entry once,
    most active first, and then takes them in turn by interest, as mapped ones: the two
    most active unmapped entries do not keep the window between them."""
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0, 0.2), roi(0.5, 0.3, 0.9), roi(0.5, 0.6, 0.5), roi(0.5, -0.3, 0.8)],
             now=0.0)
    order, focus = [], None
    for t in range(8):
        focus = m.select_focus(exclude=focus)
        m.focus(focus, now=float(t))
        order.append(focus)
    ids = [e.entry_id for e in m]
    by_activation = sorted(ids, key=lambda i: -m.get(i).activation)
    assert order[:4] == by_activation                        # each once, largest first
    assert order[4:] == by_activation                        # then the longest unattended
    assert all(m.get(i).foci == 2 and not m.get(i).mapped for i in ids)


def two_entries_and_a_place_seen_once() -> tuple[SpatialMap, int, int]:
    """Two entries settled, and a place at the far edge seen once, then out of view: it
    waits as a candidate."""
    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([at(0.5, 0.0), at(0.5, 0.4)], now=float(t))
    a, b = (e.entry_id for e in m)
    m.update([at(0.5, 0.0), at(0.5, 0.4), at(0.4, -0.9)], now=2.0)  # the far edge, once
    m.update([at(0.5, 0.0), at(0.5, 0.4)], now=3.0, visible=lambda p: p[1] > -0.5)
    assert len(m.candidates) == 1 and len(m) == 2                  # out of view: it waits
    return m, a, b


def test_a_place_seen_once_is_reached_while_visited_entries_stay_unmapped() -> None:
    """Entries focused and left unmapped do not hold the window: a place seen once (a
    candidate, e.g. an object moved out of view) wins by its interest."""
    m, a, b = two_entries_and_a_place_seen_once()
    focus, seen = None, []
    for t in range(3, 9):
        focus = m.select_focus(exclude=focus)
        m.focus(focus, now=float(t))
        seen.append(focus)
    assert not m.get(a).mapped and not m.get(b).mapped
    assert set(seen) - {a, b}, seen                          # the candidate was settled


def test_single_entry_keeps_the_window_and_empty_map_has_none() -> None:
    m = SpatialMap(CFG)
    assert m.select_focus() is None
    m.update([roi(0.5, 0.0)], now=0.0)
    (eid,) = [e.entry_id for e in m]
    assert m.select_focus(exclude=eid) == eid


def test_features_accumulate_within_a_focus() -> None:
    m = SpatialMap(CFG)
    m.update([roi(0.5, 0.0)], now=0.0)
    (eid,) = [e.entry_id for e in m]
    m.focus(eid, now=0.0)
    m.update([roi(0.5, 0.0, value=0.3, weight=0.8)], now=1.0)     # haptic: weight measured
    m.update([roi(0.5, 0.0, value=0.4)], now=2.0)                 # visual: no weight
    e = m.get(eid)
    assert e.known.all() and e.features[WEIGHT_INDEX] == pytest.approx(0.8)
    assert e.features[0] == pytest.approx(0.4)                     # freshest wins
    m.focus(eid, now=3.0)                                          # a new focus starts over
    assert not m.get(eid).known[WEIGHT_INDEX]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"association_radius": 0.0}, "association_radius"),
     ({"moved_threshold": 0.5}, "moved_threshold"),
     ({"vanish_frames": 0}, "vanish_frames"),
     ({"interest_rate": -1.0}, "interest_rate"),
     ({"settle_observations": 0}, "settle_observations"),
     ({"jitter_quantile": 1.5}, "jitter_quantile"),
     ({"jitter_prior": 0.5}, "jitter_prior"),
     ({"jitter_samples": 0}, "jitter_samples"),
     ({"max_height_per_width": 0.0}, "max_height_per_width")],
)
def test_config_rejects(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        SpatialMapConfig(**kwargs)


# -- the map holds only what is there (issue 15, item 5) -----------------------------------

SETTLE = SpatialMapConfig()   # the defaults: two agreeing observations settle an entry


def at(x: float, y: float, z: float = 0.05, width: float = 0.1,
       activation: float = 0.5) -> Roi:
    """A ROI at (x, y, z) whose measured size (``Roi.size_m``) is ``width`` metres."""
    return dataclasses.replace(roi(x, y, activation), position=(x, y, z), size_m=width)


def test_a_roi_settles_only_once_a_second_observation_agrees() -> None:
    m = SpatialMap(SETTLE)
    ch = m.update([at(0.5, 0.0), at(0.5, 0.4)], now=0.0)
    assert len(m) == 0 and ch.new == () and ch.candidates == (0, 1)
    ch = m.update([at(0.51, 0.0), at(0.5, 0.49)], now=1.0)          # 1 cm; 9 cm off
    assert len(ch.new) == 1 and len(m) == 1 and ch.candidates == (1,)
    (entry,) = list(m)
    assert entry.position == pytest.approx((0.51, 0.0, 0.05)) and entry.interest == 0.0
    ch = m.update([at(0.5, 0.49)], now=2.0)                         # agrees with its restart
    assert len(ch.new) == 1 and len(m) == 2


def test_a_candidate_in_view_and_not_seen_again_is_dropped() -> None:
    m = SpatialMap(SETTLE)
    m.update([at(0.5, 0.0), at(0.5, 0.4)], now=0.0)
    m.update([], now=1.0, visible=lambda p: p[1] < 0.2)             # (0.5, 0.4) out of view
    assert [c.position[:2] for c in m.candidates] == [pytest.approx((0.5, 0.4))]
    ch = m.update([at(0.5, 0.0)], now=2.0, visible=lambda p: True)
    assert ch.new == () and ch.candidates == (0,) and len(m) == 0    # a new start


def test_near_the_retina_edge_a_roi_keeps_its_entry_but_settles_nothing() -> None:
    m = SpatialMap(SETTLE)
    edge = lambda p: p[1] < 0.3                                       # noqa: E731
    for t in range(3):
        m.update([at(0.5, 0.0), at(0.5, 0.35)], now=float(t), visible=edge)
    assert [e.position[:2] for e in m] == [pytest.approx((0.5, 0.0))]
    (eid,) = [e.entry_id for e in m]
    ch = m.update([at(0.5, 0.01)], now=3.0, visible=lambda p: False)
    assert ch.associated == (eid,)


@pytest.mark.parametrize(("z", "width", "why"), [
    (-0.2, 0.1, "under the ground"),
    (0.7, 0.4, "higher than any object of a world file"),
    (0.45, 0.05, "a 5 cm wide region 45 cm above the ground: a false stereo match"),
])
def test_impossible_places_never_enter_the_map(z: float, width: float, why: str) -> None:
    m = SpatialMap(SETTLE)
    for t in range(3):
        ch = m.update([at(0.5, 0.0, z, width), at(0.6, 0.3)], now=float(t))
        assert ch.impossible == (0,), why
    assert [e.position[:2] for e in m] == [pytest.approx((0.6, 0.3))]


def test_possible_places_of_real_objects() -> None:
    m = SpatialMap(SETTLE)
    assert m.possible(at(0.5, 0.0, -0.03))          # jitter below the ground
    assert m.possible(at(0.5, 0.0, 0.25, 0.5))      # the centre of a 0.5 m box
    assert m.possible(at(0.5, 0.0, 0.09, 0.05))     # a prism seen along its 5 cm depth
    assert not m.possible(at(0.5, 0.0, float("nan")))


@pytest.mark.parametrize("size_m", [0.0, float("nan")])
def test_an_unmeasured_size_leaves_only_the_height_ceiling(size_m: float) -> None:
    m = SpatialMap(SETTLE)
    assert m.possible(at(0.5, 0.0, 0.3, size_m))     # a producer that fills no size_m
    assert not m.possible(at(0.5, 0.0, SETTLE.max_object_height + 0.2, size_m))


def test_the_consistency_radius_is_the_robots_own_measured_jitter() -> None:
    m = SpatialMap(dataclasses.replace(SETTLE, jitter_samples=10))
    assert m.consistency_radius() == SETTLE.jitter_prior
    rng = np.random.default_rng(0)
    truth = [(0.5, y, 0.05) for y in (-0.4, -0.2, 0.0, 0.2, 0.4)]
    for t in range(12):
        m.update([at(x + rng.normal(0, 0.01), y + rng.normal(0, 0.01)) for x, y, _ in truth],
                 now=float(t))
    assert len(m) == 5 and len(m.jitter) >= 10
    radius = m.consistency_radius()
    assert radius == pytest.approx(np.quantile(list(m.jitter), SETTLE.jitter_quantile))
    assert 0.01 < radius < SETTLE.jitter_prior     # 1 cm per axis: about 2.5 cm at 90 %


def test_a_stray_position_does_not_move_an_entry_but_a_repeated_one_does() -> None:
    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([at(0.5, 0.0)], now=float(t))
    (eid,) = [e.entry_id for e in m]
    m.set_mapped(eid, 3)
    ch = m.update([at(0.6, 0.0)], now=2.0)          # two objects seen as one, once
    assert ch.associated == (eid,) and ch.moved == ()
    assert m.get(eid).position == pytest.approx((0.5, 0.0, 0.05))
    m.update([at(0.5, 0.01)], now=3.0)
    ch = m.update([at(0.62, 0.0)], now=4.0)         # the object was moved: seen there ...
    assert ch.moved == ()
    ch = m.update([at(0.63, 0.0)], now=5.0)         # ... twice
    assert ch.moved == (eid,) and not m.get(eid).mapped
    assert m.get(eid).position == pytest.approx((0.63, 0.0, 0.05))


def test_while_the_eyes_stand_still_a_grown_window_is_a_merge_that_only_gives_the_weight(
) -> None:
    # Random 231's first focus: a box seen on its own after the shift, merged with the
    # two objects behind it after the haptic improvement (nothing had moved; fresh pixel
    # noise flipped perception's split). The merge brings the weight; its position,
    # other features and window are the blend's, not the box's.
    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([at(0.5, 0.0)], now=float(t))
    (eid,) = [e.entry_id for e in m]
    m.focus(eid, now=2.0)
    box = m.get(eid).roi                                           # 4 x 4 px
    blend = dataclasses.replace(roi(0.53, 0.0, value=0.7, weight=0.8),
                                position=(0.53, 0.0, 0.05), bbox=(0, 0, 4, 9))
    ch = m.update([blend], now=3.0, still=True)
    e = m.get(eid)
    assert ch.associated == (eid,)
    assert e.known.all() and e.features[WEIGHT_INDEX] == pytest.approx(0.8)
    assert e.features[0] == pytest.approx(0.3)                     # the box's, not 0.7
    assert e.roi.bbox == box.bbox and e.last_frame == m.frame      # seen, not lost
    assert e.position == pytest.approx((0.5, 0.0, 0.05))
    # A window that shrinks (the object parted from a neighbour) is taken.
    parted = dataclasses.replace(roi(0.5, 0.0, value=0.35), position=(0.5, 0.0, 0.05),
                                 bbox=(0, 0, 3, 3))
    m.update([parted], now=4.0, still=True)
    e = m.get(eid)
    assert e.features[0] == pytest.approx(0.35) and e.roi.bbox == (0, 0, 3, 3)
    assert e.features[WEIGHT_INDEX] == pytest.approx(0.8)          # kept for the focus
    # Random 42: the entry's first W was another object's reading; the haptic
    # improvement's fresh reading (1.6 kg) comes with a merged window and still counts.
    grown = dataclasses.replace(roi(0.53, 0.0, value=0.7, weight=0.4),
                                position=(0.53, 0.0, 0.05), bbox=(0, 0, 3, 9))
    m.update([grown], now=5.0, still=True)
    e = m.get(eid)
    assert e.features[WEIGHT_INDEX] == pytest.approx(0.4)          # touch, not pixels
    assert e.features[0] == pytest.approx(0.35) and e.roi.bbox == (0, 0, 3, 3)


def test_after_the_eyes_moved_a_grown_window_is_the_entrys_only_view() -> None:
    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([at(0.5, 0.0)], now=float(t))
    (eid,) = [e.entry_id for e in m]
    m.focus(eid, now=2.0)
    # The old window is elsewhere in the new image: the ROI is taken as it is.
    seen = dataclasses.replace(roi(0.5, 0.0, value=0.2), position=(0.5, 0.0, 0.05),
                               bbox=(20, 20, 30, 30))
    m.update([seen], now=3.0)
    e = m.get(eid)
    assert e.features[0] == pytest.approx(0.2) and e.roi.bbox == (20, 20, 30, 30)


def test_a_place_where_fixation_found_nothing_waits_for_its_interest() -> None:
    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([at(0.5, 0.0, activation=0.9), at(0.5, 0.4, activation=0.2)], now=float(t))
    lost, other = (e.entry_id for e in m)
    m.forget(lost)                                   # fixated: nothing there
    for t in (2, 3):
        m.update([at(0.52, 0.0, activation=0.9), at(0.5, 0.4, activation=0.2)],
                 now=float(t))
    (again,) = [e.entry_id for e in m if e.entry_id != other]
    assert m.get(again).inhibited and not m.get(other).inhibited
    assert m.select_focus() == other                 # the lower activation, not inhibited
    m.set_mapped(other, 1)
    m.focus(other, now=6.0)
    m.advance(10.0)                                  # interests: again 0.7, other 0.4
    assert m.select_focus() == again                 # visited by its interest
    m.set_mapped(again, 2)
    assert not m.get(again).inhibited and m.lost_places == []


def test_a_place_seen_once_is_looked_at_again_when_nothing_else_is_unmapped() -> None:
    m, a, b = two_entries_and_a_place_seen_once()
    assert m.select_focus() == a                                   # unmapped entries first
    m.set_mapped(a, 1)
    m.set_mapped(b, 2)
    m.focus(a, now=3.0)
    m.focus(b, now=3.0)
    m.advance(5.0)                                                 # candidate 0.3, a b 0.2
    seen_once = m.select_focus()
    assert seen_once not in (a, b) and m.candidates == []
    entry = m.get(seen_once)
    assert entry.position[:2] == pytest.approx((0.4, -0.9)) and not entry.mapped
    assert entry.interest == pytest.approx(0.3)


def test_a_merge_hold_takes_every_touch_feature_of_the_extended_mode() -> None:
    """What the hand measured (W, and TH and TS in the extended mode) is not the window's
    pixels: a held (merged) window still gives all of it; the visual features stay."""
    from roger_common.types import TOUCH_FEATURE_NAMES, feature_dim, feature_names
    names = feature_names("extended")
    n = feature_dim("extended")
    touch = [names.index(t) for t in TOUCH_FEATURE_NAMES]

    def look(value: float, felt: float | None, bbox: tuple[int, int, int, int]) -> Roi:
        features = np.full(n, value, np.float32)
        known = np.ones(n, bool)
        for i in touch:
            features[i], known[i] = (0.0, False) if felt is None else (felt, True)
        return Roi(roi_id=0, bbox=bbox, position=(0.5, 0.0, 0.05), features=features,
                   known=known, activation=0.5)

    m = SpatialMap(SETTLE)
    for t in range(2):
        m.update([look(0.3, None, (0, 0, 4, 4))], now=float(t))
    (eid,) = [e.entry_id for e in m]
    m.focus(eid, now=2.0)
    m.update([look(0.7, 0.6, (0, 0, 4, 9))], now=3.0, still=True)   # a merge, felt
    e = m.get(eid)
    assert e.known.all()
    assert all(e.features[i] == pytest.approx(0.6) for i in touch)
    assert e.features[names.index("H")] == pytest.approx(0.3)     # the window's own
    m.update([look(0.7, 0.2, (0, 0, 4, 9))], now=4.0, still=True)   # felt again
    assert all(m.get(eid).features[i] == pytest.approx(0.2) for i in touch)

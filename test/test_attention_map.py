"""The pre-attentional (spatial) map: association, interest, moved / vanished / new objects,
and the winner-take-all of the attention shift.

(That the core imports without ROS is checked elsewhere.)
"""

from __future__ import annotations

import numpy as np
import pytest

from roger_attention.config import SpatialMapConfig
from roger_attention.spatial_map import SpatialMap
from roger_common.errors import ConfigError
from roger_common.types import FEATURE_DIM, WEIGHT_INDEX, Roi

CFG = SpatialMapConfig(association_radius=0.1, moved_threshold=0.04, vanish_frames=2,
                       interest_rate=0.5)


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
     ({"interest_rate": -1.0}, "interest_rate")],
)
def test_config_rejects(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        SpatialMapConfig(**kwargs)

"""The spatial map as markers (issue 36, item 3): roger_attention.markers and its message.

Each entry is drawn at its position with its mapping status and interest; the focus of
attention and the last identified or stored address are drawn too; the MarkerArray is in
the ground frame and first clears the markers of the previous map.
"""

from __future__ import annotations

import numpy as np
import pytest
from visualization_msgs.msg import Marker

from roger_attention.controller import CycleRecord
from roger_attention.conversions import markers_msg
from roger_attention.markers import (
    INTEREST_BAR_M,
    MAPPED_RGBA,
    UNMAPPED_RGBA,
    MapView,
    MarkerShape,
)
from roger_attention.spatial_map import MapEntry
from roger_common import frames
from roger_common.types import FEATURE_DIM, Action, Roi, RunCounters


def entry(entry_id: int, position, mapped: bool = False, interest: float = 0.0,
          address: int = -1) -> MapEntry:
    roi = Roi(roi_id=0, bbox=(0, 0, 4, 4), position=position,
              features=np.zeros(FEATURE_DIM, np.float32), known=np.ones(FEATURE_DIM, bool))
    return MapEntry(entry_id=entry_id, position=position, roi=roi, features=roi.features,
                    known=roi.known, first_seen=0.0, last_seen=0.0, last_frame=0,
                    mapped=mapped, address=address, interest=interest)


def record(entry_id: int, position, outcome: str, address: int = -1) -> CycleRecord:
    return CycleRecord(cycle=1, state_before="000", action=Action.MAP_UPDATE,
                       state_after="000", reward=0.0, td_error=None, entry_id=entry_id,
                       position=position, bbox=None, outcome=outcome, address=address,
                       counters=RunCounters())


ENTRIES = [entry(1, (0.5, 0.2, 0.05), mapped=True, interest=2.0, address=3),
           entry(2, (0.6, -0.3, 0.04), interest=1.0),
           entry(5, (0.4, 0.0, 0.06), interest=0.0)]


def by(specs, namespace):
    return {s.marker_id: s for s in specs if s.namespace == namespace}


def test_each_entry_shows_position_status_and_interest() -> None:
    specs = MapView().markers(ENTRIES)
    spheres, bars, labels = by(specs, "entries"), by(specs, "interest"), by(specs, "labels")
    assert set(spheres) == set(labels) == {1, 2, 5}
    for e in ENTRIES:
        assert spheres[e.entry_id].position == e.position
        assert spheres[e.entry_id].shape is MarkerShape.SPHERE
        assert spheres[e.entry_id].rgba == (MAPPED_RGBA if e.mapped else UNMAPPED_RGBA)
        assert f"#{e.entry_id} " in labels[e.entry_id].text
        assert f"i={e.interest:.2f}" in labels[e.entry_id].text
    assert "mapped @3" in labels[1].text and "unmapped" in labels[2].text
    # Bars: the most interesting entry's is the full height, the others in proportion;
    # an entry of no interest has none.
    assert bars[1].scale[2] == pytest.approx(INTEREST_BAR_M)
    assert bars[2].scale[2] == pytest.approx(INTEREST_BAR_M / 2)
    assert 5 not in bars
    assert "focus" not in {s.namespace for s in specs}
    assert "address" not in {s.namespace for s in specs}


def test_focus_follows_the_entry_and_the_address_label_the_memory() -> None:
    view = MapView()
    view.note(record(2, (0.61, -0.3, 0.04), "stored", address=7))
    specs = view.markers(ENTRIES)
    # The focus is drawn at the entry's current position, not the record's.
    assert by(specs, "focus")[0].position == ENTRIES[1].position
    assert by(specs, "address")[0].text == "stored: address 7"
    view.note(record(1, (0.5, 0.2, 0.05), "identified", address=3))
    specs = view.markers(ENTRIES)
    assert by(specs, "focus")[0].position == ENTRIES[0].position
    assert by(specs, "address")[0].text == "identified: address 3"
    # A cycle that found no address keeps the last one; its focus is drawn where it was.
    view.note(record(9, (0.3, 0.3, 0.05), "undetermined"))
    specs = view.markers(ENTRIES)
    assert by(specs, "address")[0].text == "identified: address 3"
    assert by(specs, "focus")[0].position == (0.3, 0.3, 0.05)


def test_marker_array_is_in_the_ground_frame_and_clears_first() -> None:
    view = MapView()
    view.note(record(1, (0.5, 0.2, 0.05), "mapped", address=3))
    specs = view.markers(ENTRIES)
    msg = markers_msg(specs, 12.5)
    assert msg.markers[0].action == Marker.DELETEALL
    assert len(msg.markers) == len(specs) + 1
    for m in msg.markers:
        assert m.header.frame_id == frames.GROUND_FRAME
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (12, 500_000_000)
    drawn = msg.markers[1:]
    assert all(m.action == Marker.ADD for m in drawn)
    assert len({(m.ns, m.id) for m in drawn}) == len(drawn)
    types = {m.ns: m.type for m in drawn}
    assert types == {"entries": Marker.SPHERE, "interest": Marker.CYLINDER,
                     "labels": Marker.TEXT_VIEW_FACING, "focus": Marker.SPHERE,
                     "address": Marker.TEXT_VIEW_FACING}
    sphere = next(m for m in drawn if m.ns == "entries" and m.id == 2)
    assert (sphere.pose.position.x, sphere.pose.position.y) == (0.6, -0.3)
    assert sphere.pose.orientation.w == 1.0 and sphere.color.a == 1.0

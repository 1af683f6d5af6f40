"""The spatial map as a standard tool draws it: markers in the ground frame.

Each entry of the map is a sphere at its position, green once mapped and orange before;
above it a bar whose height is its interest relative to the largest interest in the map
(the entry that wins the next attention shift by interest has the tallest bar) and a text
with its id, mapping status, interest and memory address. The current focus of attention
is a translucent yellow sphere around the entry in focus, and the last address the memory
identified or stored is a text label above the place where that happened.

Plain data only (``MarkerSpec``); roger_attention.conversions turns them into a
visualization_msgs/MarkerArray. The map's positions are in the robot's base frame, which
stands on the ground frame with the identity (roger_sim.tf_tree), so they are drawn as
they are.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass

from roger_attention.controller import CycleRecord
from roger_attention.spatial_map import MapEntry

Vec3 = tuple[float, float, float]
Rgba = tuple[float, float, float, float]

#: Diameter of an entry's sphere, metres.
ENTRY_DIAMETER = 0.06
#: Height of the interest bar of the most interesting entry, metres.
INTEREST_BAR_M = 0.3
#: Diameter of the focus sphere, metres.
FOCUS_DIAMETER = 0.16
#: Height of the text labels, metres.
TEXT_HEIGHT = 0.05
MAPPED_RGBA: Rgba = (0.2, 0.8, 0.2, 1.0)
UNMAPPED_RGBA: Rgba = (1.0, 0.55, 0.0, 1.0)
INTEREST_RGBA: Rgba = (0.3, 0.5, 1.0, 0.8)
FOCUS_RGBA: Rgba = (1.0, 0.9, 0.0, 0.35)
TEXT_RGBA: Rgba = (1.0, 1.0, 1.0, 1.0)
ADDRESS_RGBA: Rgba = (1.0, 0.9, 0.0, 1.0)
#: Outcomes that name an object the memory identified, and the one of a stored object.
IDENTIFIED_OUTCOMES = frozenset({"identified", "mapped", "remapped"})
STORED_OUTCOME = "stored"


class MarkerShape(enum.Enum):
    """What a marker draws."""

    SPHERE = "sphere"
    CYLINDER = "cylinder"
    TEXT = "text"


@dataclass(frozen=True)
class MarkerSpec:
    """One marker: ``namespace`` and ``marker_id`` name it (a later one replaces it)."""

    namespace: str
    marker_id: int
    shape: MarkerShape
    position: Vec3
    scale: Vec3
    rgba: Rgba
    text: str = ""


@dataclass(frozen=True)
class AddressLabel:
    """The last address the memory identified or stored, and where."""

    address: int
    stored: bool
    position: Vec3


class MapView:
    """Follows the cycle records for what the map alone does not say (focus, last address)
    and draws the map with them."""

    def __init__(self) -> None:
        self.focus_id = -1
        self.focus_position: Vec3 | None = None
        self.label: AddressLabel | None = None

    def note(self, record: CycleRecord) -> None:
        """Take in a finished cycle: its focus, and its address if one was found or stored."""
        self.focus_id = record.entry_id
        self.focus_position = record.position
        if record.address >= 0 and record.position is not None and (
                record.outcome in IDENTIFIED_OUTCOMES or record.outcome == STORED_OUTCOME):
            self.label = AddressLabel(record.address, record.outcome == STORED_OUTCOME,
                                      record.position)

    def markers(self, entries: Iterable[MapEntry]) -> list[MarkerSpec]:
        """Every marker of the map as it stands (the receiver first clears the old ones)."""
        entries = list(entries)
        out: list[MarkerSpec] = []
        top = max((e.interest for e in entries if math.isfinite(e.interest)), default=0.0)
        focus = self.focus_position
        for e in entries:
            x, y, z = e.position
            out.append(MarkerSpec("entries", e.entry_id, MarkerShape.SPHERE, (x, y, z),
                                  (ENTRY_DIAMETER,) * 3,
                                  MAPPED_RGBA if e.mapped else UNMAPPED_RGBA))
            height = INTEREST_BAR_M * e.interest / top if top > 0 else 0.0
            if height > 1e-3:
                out.append(MarkerSpec("interest", e.entry_id, MarkerShape.CYLINDER,
                                      (x, y, z + ENTRY_DIAMETER / 2 + height / 2),
                                      (0.02, 0.02, height), INTEREST_RGBA))
            address = f" @{e.address}" if e.address >= 0 else ""
            out.append(MarkerSpec(
                "labels", e.entry_id, MarkerShape.TEXT,
                (x, y, z + ENTRY_DIAMETER + height + TEXT_HEIGHT),
                (0.0, 0.0, TEXT_HEIGHT), TEXT_RGBA,
                f"#{e.entry_id} {'mapped' if e.mapped else 'unmapped'}{address} "
                f"i={e.interest:.2f}"))
            if e.entry_id == self.focus_id:
                focus = (x, y, z)
        if focus is not None:
            out.append(MarkerSpec("focus", 0, MarkerShape.SPHERE, focus,
                                  (FOCUS_DIAMETER,) * 3, FOCUS_RGBA))
        if self.label is not None:
            x, y, z = self.label.position
            what = "stored" if self.label.stored else "identified"
            out.append(MarkerSpec("address", 0, MarkerShape.TEXT,
                                  (x, y, z + INTEREST_BAR_M + 3 * TEXT_HEIGHT),
                                  (0.0, 0.0, 1.5 * TEXT_HEIGHT), ADDRESS_RGBA,
                                  f"{what}: address {self.label.address}"))
        return out

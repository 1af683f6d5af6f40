"""The pre-attentional (spatial) map: every ROI settled at its position in the robot frame.

Each entry keeps the mapping status set by a map update, the long-term-memory address once
known, the pre-attentive activation of its freshest ROI and its interest (section 5): zero
when the entry is first settled, growing with simulated time, reset when attention focuses
on it. ROIs are associated with entries by position; moved, vanished and new objects are
noticed and the map follows.

The map holds only what is there. A ROI at an impossible place (under the ground, higher
than any object of the world, or floating higher above the ground than its own width
allows) never enters it. A ROI that matches no entry is first a candidate, and settles as
an entry only once further observations agree on its place; the radius they must agree
within is calibrated from the robot's own position jitter, measured between looks. A ROI
near the retina's edge (its position is an estimate) settles nothing, and a single stray
position does not move an entry. A place where a fixation found nothing is remembered: an
entry settled there again waits for its interest instead of winning by its activation.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from roger_attention.config import SpatialMapConfig
from roger_common.geometry import as_point
from roger_common.types import (
    FEATURE_NAMES,
    TOUCH_FEATURE_NAMES,
    Roi,
    feature_names,
    mode_of_dim,
)

Position = tuple[float, float, float]
#: Says whether a robot-frame position is currently inside the retina.
VisibleFn = Callable[[Position], bool]
#: Index of the size feature D (eq. 4) in a ROI's features.
SIZE_INDEX = FEATURE_NAMES.index("D")


def touch_indices(n: int) -> list[int]:
    """Indices of the features touch measures in a feature vector of ``n`` entries."""
    names = feature_names(mode_of_dim(n))
    return [names.index(t) for t in TOUCH_FEATURE_NAMES if t in names]
#: How many of the latest entry-to-ROI distances the jitter quantile is taken over.
JITTER_WINDOW = 256


@dataclass
class MapEntry:
    """One settled ROI.

    Attributes:
        entry_id: Unique for the lifetime of the map (never reused).
        position: Where the entry is, robot frame, metres: the position of the latest
            associated ROI that agreed with it (see ``SpatialMap._follow``).
        roi: Freshest ROI associated with the entry (``mapped`` mirrors the entry).
        features: Features of the focus so far: those of the freshest ROI, plus features it
            does not know but an earlier ROI of the same focus measured (the weight of a
            haptic improvement before a visual one).
        known: Which of ``features`` are measured.
        mapped: Mapping status, set by a map update.
        address: Long-term-memory address once the object is identified or stored; -1 before.
        interest: Grows with simulated time, zero when settled or focused (section 5).
        activation: Pre-attentive activation of the freshest ROI, [0, 1].
        first_seen: Simulated time the entry was settled.
        last_seen: Simulated time of the last associated ROI.
        last_frame: Number of the last observation (``SpatialMap.frame``) that saw it.
        mapped_position: Where the entry was when it was mapped (None while unmapped).
        misses: Consecutive observations in which its position was in view but no ROI
            matched it.
        foci: How many times attention has focused on the entry (``focus``).
        inhibited: Settled where an earlier fixation found nothing (``forget``): until
            it is mapped it wins an attention shift only by interest, as a mapped entry
            does, not by its activation (inhibition of return).
        pending: A position the latest associated ROIs agree on but the entry's does not
            (see ``SpatialMap._follow``); None when they agree.
        pending_count: Consecutive observations at ``pending``.
    """

    entry_id: int
    position: Position
    roi: Roi
    features: np.ndarray
    known: np.ndarray
    first_seen: float
    last_seen: float
    last_frame: int
    mapped: bool = False
    address: int = -1
    interest: float = 0.0
    activation: float = 0.0
    mapped_position: Position | None = None
    misses: int = 0
    inhibited: bool = False
    foci: int = 0
    pending: Position | None = None
    pending_count: int = 0


@dataclass
class Candidate:
    """A place where a ROI was seen that is not (yet) an entry.

    Attributes:
        position: Mean position of the agreeing observations, robot frame, metres.
        roi: Latest ROI seen there.
        observations: Agreeing observations so far (one per frame).
        last_frame: Number of the last observation that saw it.
        interest: Grows with simulated time from its first sighting, as an entry's does.
    """

    position: Position
    roi: Roi
    observations: int
    last_frame: int
    interest: float = 0.0


@dataclass(frozen=True)
class MapChanges:
    """What one observation changed, by entry id; ROIs by their index in the observation.

    Attributes:
        new: Entries settled by this observation.
        associated: Entries a ROI was associated with.
        moved: Mapped entries that moved (mapping status cleared).
        vanished: Entries removed because their place was in view and empty.
        candidates: ROIs kept as candidates (not yet agreed on by enough observations).
        impossible: ROIs at impossible places, left out.
    """

    new: tuple[int, ...] = ()
    associated: tuple[int, ...] = ()
    moved: tuple[int, ...] = ()
    vanished: tuple[int, ...] = ()
    candidates: tuple[int, ...] = ()
    impossible: tuple[int, ...] = ()


#: A ROI whose window's area is more than this many times the entry's, while the eyes
#: stand still, is a merge (SpatialMap._associate). Measured on four closed-loop runs
#: (inspection Q-learning, random 41 straightforward, random 43 both; seed 0): of 291
#: looks of an improvement against the look before it, the area ratio's 5th-95th
#: percentiles are 0.82-1.25; of the 9 beyond 1.4, 8 showed the object no more (7 a
#: window over two objects or mostly ground, 1 another object), against 5 of 282 below.
MERGE_GROWTH: float = 1.4


def _area(bbox: tuple[int, int, int, int]) -> int:
    return max(bbox[2] - bbox[0], 0) * max(bbox[3] - bbox[1], 0)


def _distance(a: Sequence[float], b: Sequence[float]) -> float:
    return math.dist(a, b)


@dataclass
class SpatialMap:
    """Entries by id, their association with incoming ROIs, interest and winner-take-all.

    Attributes:
        config: Radii, vanish count, interest rate, settling and workspace limits.
        entries: Entries by id, in settling order.
        candidates: Places seen but not yet settled (never attended to).
        frame: Number of observations merged so far.
        time: Simulated time the interests are brought up to.
        jitter: The latest distances between an entry and the ROI associated with it (the
            robot's own position jitter between looks), metres.
        lost_places: Where a fixation found nothing (``forget``), until an entry there is
            mapped.
    """

    config: SpatialMapConfig = field(default_factory=SpatialMapConfig)
    entries: dict[int, MapEntry] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)
    frame: int = 0
    time: float | None = None
    jitter: deque[float] = field(default_factory=lambda: deque(maxlen=JITTER_WINDOW))
    lost_places: list[Position] = field(default_factory=list)
    _next_id: int = field(default=1, init=False, repr=False)

    def __len__(self) -> int:
        return len(self.entries)

    def __iter__(self) -> Iterator[MapEntry]:
        return iter(list(self.entries.values()))

    def __contains__(self, entry_id: object) -> bool:
        return entry_id in self.entries

    def get(self, entry_id: int | None) -> MapEntry | None:
        """The entry with this id, or None (also for None or a vanished id)."""
        return None if entry_id is None else self.entries.get(entry_id)

    def advance(self, now: float) -> None:
        """Let every interest grow up to simulated time ``now`` (never backwards)."""
        if self.time is not None and now > self.time:
            grow = self.config.interest_rate * (now - self.time)
            for entry in self.entries.values():
                entry.interest += grow
            for candidate in self.candidates:
                candidate.interest += grow
        if self.time is None or now > self.time:
            self.time = now

    def consistency_radius(self) -> float:
        """How far apart two observations of one still object may be (m).

        The ``jitter_quantile`` of the measured entry-to-ROI distances once
        ``jitter_samples`` are measured, ``jitter_prior`` before; never more than
        ``association_radius``.
        """
        cfg = self.config
        if len(self.jitter) < cfg.jitter_samples:
            return cfg.jitter_prior
        radius = float(np.quantile(np.fromiter(self.jitter, float), cfg.jitter_quantile))
        return min(radius, cfg.association_radius)

    def possible(self, roi: Roi) -> bool:
        """Whether a ROI can be an object of the workspace.

        Objects rest on the ground: a ROI's centre below the ground by more than the
        consistency radius, above ``max_object_height``, or higher above the ground than
        ``max_height_per_width`` times its own measured width (plus the radius) is a
        false match of the two retinas, never an object. A ROI whose size was not
        measured (``size_m`` 0, the message default, or not finite: a producer that does
        not fill it) is held to ``max_object_height`` alone.
        """
        cfg = self.config
        tolerance = self.consistency_radius()
        z = float(roi.position[2])
        width = float(roi.size_m)
        ceiling = cfg.max_object_height
        if np.isfinite(width) and width > 0.0:
            ceiling = min(ceiling, cfg.max_height_per_width * width)
        return bool(np.isfinite(roi.position).all()) and -tolerance <= z <= ceiling + tolerance

    def update(self, rois: Sequence[Roi], now: float,
               visible: VisibleFn | None = None, still: bool = False) -> MapChanges:
        """Merge one ROI array into the map.

        ROIs at impossible places (:meth:`possible`) are left out. The others and the
        entries are paired greedily by increasing distance, each at most once, within
        ``association_radius``. A paired mapped entry that drifted more than
        ``moved_threshold`` from where it was mapped has moved: its mapping status is
        cleared. An unpaired ROI goes to the nearest candidate within the radius, or starts
        a new one; a candidate settles as an entry (interest 0) once
        ``settle_observations`` observations agreed within :meth:`consistency_radius`. An
        unpaired entry whose position ``visible`` reports in view for ``vanish_frames``
        observations in a row has vanished and is removed; a candidate in view and not
        seen again is dropped at once. Without ``visible`` nothing is ever removed, because
        the map cannot tell an object gone from one out of view.

        Args:
            rois: The ROIs of one frame, positions in the robot frame.
            now: Simulated time of the frame.
            visible: Whether a map position is currently inside the retina.
            still: The eyes have not moved since the previous frame (an improvement
                trial): a ROI whose window grew beyond ``MERGE_GROWTH`` times its entry's
                is then a merge and replaces neither the entry's position, visual
                features nor window, only its weight (``_associate``).

        Returns:
            The ids of new, associated, moved and vanished entries; the indices of ROIs
            kept as candidates and of impossible ones.
        """
        self.advance(now)
        self.frame += 1
        radius = self.config.association_radius
        possible = [self.possible(roi) for roi in rois]
        impossible = [k for k, ok in enumerate(possible) if not ok]
        usable = [k for k, ok in enumerate(possible) if ok]
        pairs = sorted(
            (_distance(rois[k].position, e.position), k, e.entry_id)
            for k in usable for e in self.entries.values()
            if _distance(rois[k].position, e.position) <= radius
        )
        roi_used: set[int] = set()
        entry_used: set[int] = set()
        moved: list[int] = []
        for distance, k, entry_id in pairs:
            if k in roi_used or entry_id in entry_used:
                continue
            roi_used.add(k)
            entry_used.add(entry_id)
            self.jitter.append(distance)
            if self._associate(self.entries[entry_id], rois[k], now, still):
                moved.append(entry_id)
        # A ROI placed near the retina's edge is mostly one cut by it, whose position is an
        # estimate (docs/perception.md): it keeps its entry alive but settles no new one.
        left = [k for k in usable if k not in roi_used
                and (visible is None or visible(as_point(rois[k].position)))]
        new, waiting = self._candidates(rois, left, now, visible)
        vanished: list[int] = []
        if visible is not None:
            for entry in list(self.entries.values()):
                if entry.entry_id in entry_used or entry.entry_id in new:
                    continue
                if visible(entry.position):
                    entry.misses += 1
                    if entry.misses >= self.config.vanish_frames:
                        del self.entries[entry.entry_id]
                        vanished.append(entry.entry_id)
        return MapChanges(tuple(new), tuple(sorted(entry_used)), tuple(moved),
                          tuple(vanished), tuple(waiting), tuple(impossible))

    def _candidates(self, rois: Sequence[Roi], left: list[int], now: float,
                    visible: VisibleFn | None) -> tuple[list[int], list[int]]:
        """Unpaired ROIs meet the candidates: returns (settled entry ids, ROIs waiting)."""
        cfg = self.config
        agree = self.consistency_radius()
        pairs = sorted(
            (_distance(rois[k].position, c.position), k, j)
            for k in left for j, c in enumerate(self.candidates)
            if _distance(rois[k].position, c.position) <= cfg.association_radius
        )
        roi_of: dict[int, int] = {}   # candidate index -> ROI index
        for distance, k, j in pairs:
            if j in roi_of or k in roi_of.values():
                continue
            roi_of[j] = k
            c = self.candidates[j]
            if distance <= agree:
                n = c.observations
                mean = (np.asarray(c.position) * n + np.asarray(rois[k].position)) / (n + 1)
                c.position, c.observations = as_point(mean), n + 1
            else:  # the same place, not the same position: start again from this one
                c.position, c.observations = as_point(rois[k].position), 1
            c.roi, c.last_frame = rois[k], self.frame
        # A candidate in view and not seen again was a passing error; one out of view
        # cannot be told gone and waits.
        kept: list[tuple[Candidate, int | None]] = [
            (c, roi_of.get(j)) for j, c in enumerate(self.candidates)
            if j in roi_of or visible is None or not visible(c.position)]
        taken = set(roi_of.values())
        kept += [(Candidate(as_point(rois[k].position), rois[k], 1, self.frame), k)
                 for k in left if k not in taken]
        settled: list[int] = []
        waiting: list[int] = []
        self.candidates = []
        for c, index in kept:
            if c.observations >= cfg.settle_observations:
                settled.append(self._settle(c.roi, now))
                continue
            self.candidates.append(c)
            if index is not None:
                waiting.append(index)
        return settled, sorted(waiting)

    def _settle(self, roi: Roi, now: float) -> int:
        entry_id = self._next_id
        self._next_id += 1
        self.entries[entry_id] = MapEntry(
            entry_id=entry_id, position=as_point(roi.position),
            roi=dataclasses.replace(roi, mapped=False),
            features=np.asarray(roi.features, np.float32).copy(),
            known=np.asarray(roi.known, bool).copy(),
            first_seen=now, last_seen=now, last_frame=self.frame,
            activation=float(roi.activation),
            inhibited=self._near_lost_place(as_point(roi.position)))
        return entry_id

    def _associate(self, entry: MapEntry, roi: Roi, now: float, still: bool) -> bool:
        # While the eyes stood still, a ROI whose window grew beyond MERGE_GROWTH times
        # the entry's is the object's region merged with a neighbour's (fresh pixel noise
        # flipped perception's split): it keeps the entry alive and gives its weight (W
        # is touch, the newest reading at the place, not the window's pixels: a haptic
        # improvement's fresh reading replaces an older one), but its position, other
        # features and window are the blend's: the entry keeps those of its last ROI,
        # whose window is still on the same pixels, and takes of them only what it has
        # not measured yet. A window that shrinks (the object parted from a neighbour) is
        # taken. After the eyes moved, the old window means nothing in the new image: the
        # ROI is taken as it is.
        before = _area(entry.roi.bbox)
        hold = still and before > 0 and _area(roi.bbox) > MERGE_GROWTH * before
        if not hold:
            self._follow(entry, as_point(roi.position))
        entry.activation = float(roi.activation)
        entry.last_seen = now
        entry.last_frame = self.frame
        entry.misses = 0
        known = np.asarray(roi.known, bool)
        if hold:
            take = known & ~entry.known
            # What touch measured (W, and the tactile shape in the extended mode) is the
            # hand's, not the window's pixels.
            touch = touch_indices(len(known))
            take[touch] = known[touch]
        else:
            take = known
        entry.features[take] = np.asarray(roi.features, np.float32)[take]
        entry.known |= known
        moved = (entry.mapped and entry.mapped_position is not None and
                 _distance(entry.position, entry.mapped_position) > self.config.moved_threshold)
        if moved:
            self.clear_mapping(entry.entry_id)
        entry.roi = dataclasses.replace(entry.roi if hold else roi, mapped=entry.mapped)
        return moved

    def _follow(self, entry: MapEntry, seen: Position) -> None:
        """Move the entry's position to ``seen`` when it agrees with it (within the
        consistency radius), or once ``settle_observations`` observations in a row agree on
        another place: a single stray position (a region cut by the retina's edge, two
        objects seen as one) does not drag the entry away from its object."""
        radius = self.consistency_radius()
        if _distance(seen, entry.position) <= radius:
            entry.position, entry.pending, entry.pending_count = seen, None, 0
            return
        if entry.pending is not None and _distance(seen, entry.pending) <= radius:
            entry.pending_count += 1
        else:
            entry.pending_count = 1
        entry.pending = seen
        if entry.pending_count >= self.config.settle_observations:
            entry.position, entry.pending, entry.pending_count = seen, None, 0

    def forget(self, entry_id: int) -> None:
        """Remove an entry: the eyes fixated its place and saw nothing there.

        The place is remembered: an entry settled there again is ``inhibited``.
        """
        entry = self.entries.pop(entry_id, None)
        if entry is None:
            return
        radius = self.consistency_radius()
        self.lost_places = [p for p in self.lost_places
                            if _distance(p, entry.position) > radius]
        self.lost_places.append(entry.position)

    def _near_lost_place(self, position: Position) -> bool:
        # The association radius: what the map takes for one place. A fixated object that
        # perception fails to separate comes back 3-8 cm from where it was lost (measured
        # on worlds/inspection.yaml), beyond the consistency radius.
        radius = self.config.association_radius
        return any(_distance(position, p) <= radius for p in self.lost_places)

    def focus(self, entry_id: int, now: float) -> None:
        """Attention focuses on the entry: its interest resets and its feature
        accumulation restarts from its freshest ROI."""
        self.advance(now)
        entry = self.entries[entry_id]
        entry.interest = 0.0
        entry.foci += 1
        entry.features = np.asarray(entry.roi.features, np.float32).copy()
        entry.known = np.asarray(entry.roi.known, bool).copy()

    def keep_focus(self, entry_id: int, now: float) -> None:
        """Attention stays on the entry: its interest stays zero."""
        self.advance(now)
        entry = self.entries.get(entry_id)
        if entry is not None:
            entry.interest = 0.0

    def set_mapped(self, entry_id: int, address: int) -> None:
        """A map update: mapping status 1, the address when known, the mapped position."""
        entry = self.entries[entry_id]
        entry.mapped = True
        entry.inhibited = False
        radius = self.consistency_radius()
        self.lost_places = [p for p in self.lost_places
                            if _distance(p, entry.position) > radius]
        if address >= 0:
            entry.address = address
        entry.mapped_position = entry.position
        entry.roi = dataclasses.replace(entry.roi, mapped=True)

    def clear_mapping(self, entry_id: int) -> None:
        """The map's record of this entry is stale (moved, or a different object now)."""
        entry = self.entries[entry_id]
        entry.mapped = False
        entry.mapped_position = None
        entry.roi = dataclasses.replace(entry.roi, mapped=False)

    def restore_mapped(self, places: Sequence[tuple[Position, int]]) -> list[int]:
        """Mark again as mapped the entries at places that were mapped before a restart.

        Each place (position, address) goes to the nearest unmapped entry within
        ``association_radius``, in the order given; a place with no such entry is dropped
        (the object is gone or out of view, and will be mapped again when seen).

        Returns:
            The ids of the entries mapped again.
        """
        done = []
        for position, address in places:
            near = [(_distance(e.position, position), e.entry_id)
                    for e in self.entries.values() if not e.mapped]
            if near and min(near)[0] <= self.config.association_radius:
                entry_id = min(near)[1]
                self.set_mapped(entry_id, int(address))
                done.append(entry_id)
        return done

    def mapped_places(self) -> list[tuple[Position, int]]:
        """(position, address) of every mapped entry, for :meth:`restore_mapped`."""
        return [(e.position, e.address) for e in self.entries.values() if e.mapped]

    def all_mapped(self) -> bool:
        """True when every entry has mapping status 1 (also for an empty map)."""
        return all(e.mapped for e in self.entries.values())

    def mapped_positions(self) -> list[Position]:
        """Positions of the mapped entries, in settling order."""
        return [e.position for e in self.entries.values() if e.mapped]

    def select_focus(self, exclude: int | None = None) -> int | None:
        """The attention shift's winner-take-all (section 2 and section 5).

        While some entry is unmapped and was never focused (and is not ``inhibited``), the
        one of largest pre-attentive activation wins: every object is visited at least once
        (section 5, "all objects in the environment are visited at least once");
        otherwise the entry or candidate of largest interest, which keeps the robot
        vigilant. An entry focused and left unmapped (a policy that shifted before its
        final trial) then competes by its interest, as a mapped one does: it comes back in
        turn, and does not keep the robot from the rest, a place seen once included. A
        candidate that wins (a place seen once, from a look that no later look covered) is
        settled as an entry then, so that the shift looks at it again. The current focus
        ``exclude`` only wins when it is the only entry. Ties go to the oldest entry.

        Returns:
            The winning entry id, or None for an empty map without candidates.
        """
        rivals = [e for e in self.entries.values() if e.entry_id != exclude]
        if not rivals:
            rivals = list(self.entries.values())
        unmapped = [e for e in rivals if not e.mapped and not e.inhibited and e.foci == 0]
        if unmapped:
            return max(unmapped, key=lambda e: (e.activation, -e.entry_id)).entry_id
        best = max(rivals, key=lambda e: (e.interest, -e.entry_id), default=None)
        waiting = max(self.candidates, key=lambda c: c.interest, default=None)
        if waiting is not None and (best is None or waiting.interest > best.interest):
            self.candidates.remove(waiting)
            entry_id = self._settle(waiting.roi, self.time or 0.0)
            self.entries[entry_id].interest = waiting.interest
            return entry_id
        return None if best is None else best.entry_id

"""The other eye's view of a group: objects whose outlines line up in one retina.

Two objects one behind the other whose outlines line up in the left retina leave the
convexity test (``grouping``) nothing to see: no notch where they meet. The right eye
stands 16 cm beside the left one, so the two objects, 10-20 cm apart in depth, shift
against each other by the difference of their disparities (2-4 px at 1 m, 128 px): their
outlines no longer line up there, and the right retina's own grouping keeps them apart
(or shows ground between them). Measured on the scan gazes and a gaze at every object
of worlds/inspection.yaml, both retinas grouped by intensity and convexity alone: of 18
groups of the left retina holding two objects, 2 held the same two in the right retina,
and the box pair c03_2/c07_0 (merged in 4 left frames) never did. docs/perception.md,
step 6b, has what it changes over the robot's looks and in closed loop.

A group of the left retina is split where its fragments (each one intensity-homogeneous
surface: a face, a plain object, a texture cell) fall, placed at the group's depth, on
different groups of the right retina. Only fragments are moved, never pixels: a cut runs
where the left retina shows an intensity edge.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from roger_perception.config import PerceptionConfig
from roger_perception.grouping import absorb_slivers, adjacency, group_fragments, owner_lut
from roger_perception.plane_sweep import PlaneSweep
from roger_perception.segmentation import (
    foreground_mask,
    fragment_labels,
    split_at_notches,
    sure_ground,
)

#: A fragment belongs to the right-retina group that holds at least this share of its
#: pixels placed in the right retina (on objects there).
MAJORITY = 0.6
#: ... and at least this share of its placed pixels must land on objects at all.
ON_OBJECTS = 0.5
#: A right-retina group is a merge of two left groups when each brings this share of the
#: pixels that fall on it.
MIXED_SHARE = 0.25


def group_labels(image: np.ndarray, cfg: PerceptionConfig) -> np.ndarray:
    """Object groups of one retina by intensity and convexity alone (no stereo): the
    left retina's steps 1, 2, 5 (without the depth seeding) and 6 (docs/perception.md).

    Returns:
        (H, W) int32 labels, 0 ground.
    """
    fg, bg = foreground_mask(image, cfg)
    frag = absorb_slivers(fragment_labels(image, fg, bg, cfg), cfg.min_roi_pixels)
    if int(frag.max()) == 0:
        return frag.astype(np.int32)
    ground = sure_ground(image, fg)
    frag = split_at_notches(frag, image, ground, bg, cfg.notch_px, cfg.min_roi_pixels)
    owner = group_fragments(frag, ground, adjacency(frag), cfg.min_roi_pixels, cfg.notch_px)
    return owner_lut(owner, int(frag.max()))[frag]


def split_by_other_eye(frag: np.ndarray, owner: Mapping[int, int],
                       depth: Mapping[int, float] | np.ndarray, sweep: PlaneSweep,
                       other: np.ndarray, min_pixels: int) -> dict[int, int]:
    """Split the left retina's groups whose fragments fall on different groups of the
    right retina (module docstring).

    Args:
        frag: Fragment labels of the left retina (0 ground).
        owner: Group (a representative fragment) of every fragment.
        depth: Depth (m, left optical axis) of every group, indexed by its representative.
        sweep: The frame's geometry (left pixel at a depth -> right pixel).
        other: Group labels of the right retina (``group_labels``).
        min_pixels: Each part of a split holds at least this many pixels.

    Returns:
        The new owner of every fragment (unchanged groups keep their representative; a
        split group's parts are represented by their smallest fragment label).
    """
    members = _members(owner)
    new = dict(owner)
    if all(len(ms) == 1 for ms in members.values()):
        return new
    # Where every fragment falls in the right retina, at its group's depth.
    side = _falls_on(frag, owner, depth, sweep, other)
    # A right-retina group that holds large parts of two left groups merges there what
    # the left retina keeps apart: it says nothing about where either group ends. (A
    # sliver the left retina cut off an object does not count.)
    area = np.bincount(frag.ravel())
    held: dict[int, dict[int, int]] = {}
    for p, r in side.items():
        by_group = held.setdefault(r, {})
        by_group[owner[p]] = by_group.get(owner[p], 0) + int(area[p])
    mixed = {r: sum(n >= MIXED_SHARE * sum(by.values()) for n in by.values()) > 1
             for r, by in held.items()}
    touching: dict[tuple[int, int], int] | None = None
    edge = _on_edge(frag)
    for g, ms in members.items():
        if len(ms) < 2 or any(edge[p] for p in ms):
            continue
        # Fragments on a right group this group holds nearly alone.
        clear = {p: side[p] for p in ms if p in side and not mixed[side[p]]
                 and held[side[p]][g] >= (1.0 - MIXED_SHARE) * sum(held[side[p]].values())}
        if len(set(clear.values())) < 2:
            continue
        if touching is None:
            touching = adjacency(frag)
        parts = _parts(ms, clear, touching, area)
        if min(sum(int(area[p]) for p in part) for part in parts.values()) < min_pixels:
            continue
        for part in parts.values():
            rep = min(part)
            for p in part:
                new[p] = rep
    return _join_pieces(new, side, frag, area, touching)


def _join_pieces(owner: dict[int, int], side: Mapping[int, int], frag: np.ndarray,
                 area: np.ndarray, touching: dict[tuple[int, int], int] | None
                 ) -> dict[int, int]:
    """A small group of the left retina (a piece the convexity test or a split cut off an
    object) whose fragments all fall on the right-retina group of the object it touches
    joins that object: there it is part of it. Small: under ``MIXED_SHARE`` of what falls
    on that right group."""
    groups = _members(owner)
    held: dict[int, dict[int, int]] = {}
    for g, ms in groups.items():
        on = {side.get(p, 0) for p in ms}
        if len(on) == 1 and 0 not in on:  # the whole group falls on one right group
            r = on.pop()
            held.setdefault(r, {})[g] = sum(int(area[p]) for p in ms)
    new = dict(owner)
    for by in held.values():
        if len(by) < 2:
            continue
        total = sum(by.values())
        main = max(by, key=lambda g: by[g])
        for g, n in by.items():
            if g == main or n >= MIXED_SHARE * total:
                continue
            if touching is None:
                touching = adjacency(frag)
            if any(_shared(touching, p, q) for p in groups[g] for q in groups[main]):
                for p in groups[g]:
                    new[p] = main
    return new


def _members(owner: Mapping[int, int]) -> dict[int, list[int]]:
    """The fragments of every group."""
    members: dict[int, list[int]] = {}
    for p, g in owner.items():
        members.setdefault(g, []).append(p)
    return members


def _shared(touching: Mapping[tuple[int, int], int], p: int, q: int) -> int:
    """Boundary length two fragments share (``adjacency`` keys pairs smaller first)."""
    return touching.get((min(p, q), max(p, q)), 0)


def _on_edge(frag: np.ndarray) -> np.ndarray:
    """Whether each fragment label touches the retina's edge."""
    on = np.zeros(int(frag.max()) + 1, bool)
    for line in (frag[0], frag[-1], frag[:, 0], frag[:, -1]):
        on[line] = True
    return on


def _falls_on(frag: np.ndarray, owner: Mapping[int, int],
              depth: Mapping[int, float] | np.ndarray, sweep: PlaneSweep,
              other: np.ndarray) -> dict[int, int]:
    """The right-retina group each fragment's pixels fall on, placed at its group's depth
    (all fragments in one projection); fragments of which too few land on objects there,
    or with no group holding a clear majority, are left out."""
    h, w = other.shape
    rows, cols = np.nonzero(frag)
    lab = frag[rows, cols]
    n = int(frag.max()) + 1
    z = np.full(n, np.nan)
    for p, g in owner.items():
        d = float(depth[g])
        if np.isfinite(d) and d > 0:
            z[p] = d
    ok = np.isfinite(z[lab])
    rows, cols, lab = rows[ok], cols[ok], lab[ok]
    mu, mv, ahead = sweep.right_pixels(cols + 0.5, rows + 0.5, z[lab])
    cu, cv = np.floor(mu).astype(np.int64), np.floor(mv).astype(np.int64)
    inside = ahead & (cu >= 0) & (cu < w) & (cv >= 0) & (cv < h)
    seen = np.zeros(lab.size, np.int64)
    seen[inside] = other[cv[inside], cu[inside]]
    area = np.bincount(lab, minlength=n)
    on = seen > 0
    m = int(other.max()) + 1
    counts = np.bincount(lab[on] * m + seen[on], minlength=n * m).reshape(n, m)
    landed = counts.sum(axis=1)
    best = counts.argmax(axis=1)
    share = counts[np.arange(n), best]
    # At least half a pixel landed, so ``landed`` > 0 wherever this holds.
    good = (landed >= ON_OBJECTS * np.maximum(area, 1)) & (share >= MAJORITY * landed)
    return {int(p): int(best[p]) for p in owner if good[p]}


def _parts(members: list[int], side: dict[int, int], touching: Mapping[tuple[int, int], int],
           area: np.ndarray) -> dict[int, list[int]]:
    """The fragments of one group by the right-retina group they fall on; a fragment that
    fell on none (or on several) joins the part it shares the longest boundary with, or
    the largest part."""
    parts: dict[int, list[int]] = {}
    for p, r in side.items():
        parts.setdefault(r, []).append(p)
    rest = [p for p in members if p not in side]
    while rest:
        placed = False
        for p in list(rest):
            best, length = None, 0
            for r, ms in parts.items():
                n = sum(_shared(touching, p, q) for q in ms)
                if n > length:
                    best, length = r, n
            if best is not None:
                parts[best].append(p)
                rest.remove(p)
                placed = True
        if not placed:
            largest = max(parts, key=lambda r: sum(int(area[q]) for q in parts[r]))
            parts[largest] += rest
            rest = []
    return parts

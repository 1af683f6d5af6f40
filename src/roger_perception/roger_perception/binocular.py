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
different groups of the right retina (``split_by_other_eye``): a cut runs where the left
retina shows an intensity edge. Before that, a single fragment that holds two objects of
about one grey is cut when its parts fall on two right groups and the plane sweep puts
them at different depths (``split_fragments_by_other_eye``): a watershed on the left
image draws that cut.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from roger_perception.config import PerceptionConfig
from roger_perception.grouping import absorb_slivers, adjacency, group_fragments, owner_lut
from roger_perception.plane_sweep import PlaneSweep, SampledCosts
from roger_perception.segmentation import (
    foreground_mask,
    fragment_labels,
    label_boxes,
    seed_by_depth,
    split_at_notches,
    sure_ground,
    watershed_grey,
    watershed_part,
)

#: A fragment belongs to the right-retina group that holds at least this share of its
#: pixels placed in the right retina (on objects there).
MAJORITY = 0.6
#: ... and at least this share of its placed pixels must land on objects at all.
ON_OBJECTS = 0.5
#: A right-retina group is a merge of two left groups when each brings this share of the
#: pixels that fall on it.
MIXED_SHARE = 0.25
#: A pixel of a left fragment seeds the part of the right group it falls on only when it
#: falls this deep (px) inside that group: placed at one depth for the whole fragment,
#: the parts of two objects land a few pixels off their own (their disparities differ by
#: 2-5 px at 1 m), so pixels near the groups' border do not say which one they belong to.
SEED_INSIDE_PX = 2.0
#: A fragment is cut only where at least this share of it (and ``min_roi_pixels``) falls
#: on the second right group.
PIECE_SHARE = 0.1


@dataclass(frozen=True)
class Landing:
    """Where the left retina's fragment pixels fall in the right retina (``landing``),
    projected once per frame for both splits.

    Attributes:
        rows, cols, lab: Left pixels (with a usable depth) and their fragment labels.
        seen: Right-retina group each pixel falls on (0 ground or outside).
        cu, cv: Right-retina pixel it falls on (-1 outside).
        counts: (fragments + 1, right groups + 1) pixels of each fragment on each group.
        area: Pixels of every fragment label.
    """

    rows: np.ndarray
    cols: np.ndarray
    lab: np.ndarray
    seen: np.ndarray
    cu: np.ndarray
    cv: np.ndarray
    counts: np.ndarray
    area: np.ndarray


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


def split_fragments_by_other_eye(frag: np.ndarray, owner: Mapping[int, int], land: Landing,
                                 other: np.ndarray, image: np.ndarray, ground: np.ndarray,
                                 bg: float, costs: SampledCosts, cfg: PerceptionConfig
                                 ) -> tuple[np.ndarray, dict[int, int]]:
    """Cut a left-retina fragment that falls on two groups of the right retina.

    Two objects of about the same grey, one behind the other, can make one fragment in
    the left retina (no intensity edge, no notch between them) and two groups in the
    right one, where their outlines shift against each other. A fragment is cut when, at
    its group's depth, it holds its main right group nearly alone, at least
    ``PIECE_SHARE`` of it (and ``min_roi_pixels``) falls on a second right group that it
    holds nearly alone too (the cut-off part is a group of its own) or whose rest comes
    from one other left group (the part joins that group), and the two parts' depths,
    measured by the plane sweep, are two or more hypotheses apart
    (``segmentation.seed_by_depth``): a right retina that splits one object (a face, a
    shading edge) leaves the parts at one depth, and the fragment whole. The pixels that
    fall at least ``SEED_INSIDE_PX`` inside either group seed a watershed on the left
    image, which draws the cut.

    Args:
        frag: Fragment labels of the left retina (0 ground).
        owner: Group (a representative fragment) of every fragment.
        land: Where ``frag``'s pixels fall in the right retina at their group's depth
            (``landing``).
        other: Group labels of the right retina (``group_labels``).
        image: The left retina.
        ground: Sure ground of the left retina (``segmentation.sure_ground``).
        bg: Ground level of the left retina.
        costs: The plane sweep's sampled costs of the left retina.
        cfg: Gives ``min_roi_pixels`` and ``depth_sigmas``.

    Returns:
        (fragment labels, owner): every new fragment is a group of its own; unchanged
        when nothing is cut.
    """
    min_pixels = cfg.min_roi_pixels
    counts = land.counts
    held = counts.sum(axis=0)
    # Per right group, the pixels each left group brings to it.
    groups = sorted(set(owner.values()))
    index = {g: i for i, g in enumerate(groups)}
    by_group = np.zeros((len(groups), counts.shape[1]), np.int64)
    for p, g in owner.items():
        by_group[index[g]] += counts[p]
    edge = _on_edge(frag)
    cuts: list[tuple[int, int, int, int | None]] = []
    for p in sorted(owner):
        c = counts[p]
        landed = int(c.sum())
        if land.area[p] < 2 * min_pixels or edge[p] or landed < ON_OBJECTS * land.area[p]:
            continue
        ra, rb = (int(r) for r in np.argsort(-c)[:2])
        if ra == 0 or rb == 0 or c[ra] < (1.0 - MIXED_SHARE) * held[ra]:
            continue  # p does not hold its main right group nearly alone
        if c[rb] < max(PIECE_SHARE * landed, min_pixels):
            continue
        if c[rb] >= (1.0 - MIXED_SHARE) * held[rb]:
            cuts.append((p, ra, rb, None))  # two objects in one fragment
            continue
        # A piece of an object the left retina shows mostly as another group: the rest
        # of that right group comes from one other left group, which the piece joins.
        rest = by_group[:, rb].copy()
        rest[index[owner[p]]] -= c[rb]
        other_group = int(np.argmax(rest))
        if (groups[other_group] != owner[p]
                and rest[other_group] >= (1.0 - MIXED_SHARE) * (held[rb] - c[rb])):
            cuts.append((p, ra, rb, groups[other_group]))
    if not cuts:
        return frag, dict(owner)
    inside = _inside(other)
    out = frag.copy()
    new = dict(owner)
    boxes = label_boxes(frag)
    grey = watershed_grey(image, bg)
    height, width = frag.shape
    next_label = int(frag.max()) + 1
    for p, ra, rb, joins in cuts:
        by0, bx0, by1, bx1 = boxes[p]
        y0, y1 = max(by0 - 1, 0), min(by1 + 1, height)
        x0, x1 = max(bx0 - 1, 0), min(bx1 + 1, width)
        mask = out[y0:y1, x0:x1] == p
        markers = np.where(mask, 0, 3).astype(np.int32)
        sel = land.lab == p
        deep = np.zeros(int(sel.sum()), bool)
        on = land.cu[sel] >= 0
        deep[on] = inside[land.cv[sel][on], land.cu[sel][on]] >= SEED_INSIDE_PX
        r, cc, seen = land.rows[sel] - y0, land.cols[sel] - x0, land.seen[sel]
        for k, group in ((1, ra), (2, rb)):
            here = deep & (seen == group)
            markers[r[here], cc[here]] = k
        if min((markers == 1).sum(), (markers == 2).sum()) < 0.25 * min_pixels:
            continue
        if not seed_by_depth(markers, mask, ground[y0:y1, x0:x1], costs, (y0, x0),
                             cfg.depth_sigmas):
            continue  # one depth: the right retina split one object
        part = watershed_part(grey[y0:y1, x0:x1], markers, mask, min_pixels)
        if part is None:
            continue
        crop = out[y0:y1, x0:x1]
        crop[part] = next_label  # watershed lines stay with the first part
        new[next_label] = next_label if joins is None else joins
        next_label += 1
    return out, new


def _inside(labels: np.ndarray) -> np.ndarray:
    """Distance (px) of every pixel from the nearest pixel of another label (ground
    included): how deep inside its own group a pixel lies."""
    h, w = labels.shape
    border = np.zeros((h, w), bool)
    border[:, 1:] |= labels[:, 1:] != labels[:, :-1]
    border[:, :-1] |= labels[:, 1:] != labels[:, :-1]
    border[1:, :] |= labels[1:, :] != labels[:-1, :]
    border[:-1, :] |= labels[1:, :] != labels[:-1, :]
    return cv2.distanceTransform((~border).astype(np.uint8), cv2.DIST_L2, 3)


def split_by_other_eye(frag: np.ndarray, owner: Mapping[int, int], land: Landing,
                       min_pixels: int,
                       apart: Callable[[Sequence[int], Sequence[int]], bool] | None = None
                       ) -> dict[int, int]:
    """Split the left retina's groups whose fragments fall on different groups of the
    right retina (module docstring).

    Args:
        frag: Fragment labels of the left retina (0 ground).
        owner: Group (a representative fragment) of every fragment.
        land: Where ``frag``'s pixels fall in the right retina at their group's depth
            (``landing``).
        min_pixels: Each part of a split holds at least this many pixels.
        apart: Whether two sets of fragments lie at different depths (``depths_apart``);
            without it no fragment changes group (``_hand_over``).

    Returns:
        The new owner of every fragment (unchanged groups keep their representative; a
        split group's parts are represented by their smallest fragment label).
    """
    members = _members(owner)
    new = dict(owner)
    if all(len(ms) == 1 for ms in members.values()):
        return new
    side = _falls_on(land, owner)
    # A right-retina group that holds large parts of two left groups merges there what
    # the left retina keeps apart: it says nothing about where either group ends. (A
    # sliver the left retina cut off an object does not count.)
    area = land.area
    held: dict[int, dict[int, int]] = {}
    for p, r in side.items():
        by_group = held.setdefault(r, {})
        by_group[owner[p]] = by_group.get(owner[p], 0) + int(area[p])
    mixed = {r: sum(n >= MIXED_SHARE * sum(by.values()) for n in by.values()) > 1
             for r, by in held.items()}
    touching: dict[tuple[int, int], int] | None = None
    edge = _on_edge(frag)
    main = _main_groups(members, side, area)
    for g, ms in members.items():
        if len(ms) < 2 or any(edge[p] for p in ms):
            continue
        # Fragments on a right group this group holds nearly alone.
        clear = {p: side[p] for p in ms if p in side and not mixed[side[p]]
                 and held[side[p]][g] >= (1.0 - MIXED_SHARE) * sum(held[side[p]].values())}
        if len(set(clear.values())) == 1 and apart is not None:
            if touching is None:
                touching = adjacency(frag)
            _hand_over(g, ms, set(clear.values()), side, held, main, touching, new, apart)
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


def _main_groups(members: Mapping[int, list[int]], side: Mapping[int, int],
                 area: np.ndarray) -> dict[int, int]:
    """The right-retina group on which most of each left group's pixels fall."""
    main: dict[int, int] = {}
    for g, ms in members.items():
        on: dict[int, int] = {}
        for p in ms:
            if p in side:
                on[side[p]] = on.get(side[p], 0) + int(area[p])
        if on:
            main[g] = max(on, key=lambda r: on[r])
    return main


def _hand_over(g: int, members: list[int], own: set[int], side: Mapping[int, int],
               held: Mapping[int, Mapping[int, int]], main: Mapping[int, int],
               touching: Mapping[tuple[int, int], int], owner: dict[int, int],
               apart: Callable[[Sequence[int], Sequence[int]], bool]) -> None:
    """Fragments of group ``g`` that fall on the right-retina group of another left group
    ``h`` they touch (the rest of that right group comes from ``h``, and it is where
    most of ``h`` falls) change to ``h`` (in ``owner``), while ``g`` keeps a right group
    ``own`` it holds nearly alone: the left retina joined a face of one object to another
    object and kept the first object's other faces apart (inspection's c03_2 top face with
    c07_0, its front face on its own). Only a fragment at another depth than the rest of
    ``g`` changes (``apart``): where the right retina joins two objects, a piece of ``g``'s
    own object falls on that group too (touching.yaml's prism beside the cylinder)."""
    for p in members:
        r = side.get(p)
        if r is None or r in own:
            continue
        others = {h: n for h, n in held[r].items() if h != g}
        if not others:
            continue
        h = max(others, key=lambda k: others[k])
        if others[h] < (1.0 - MIXED_SHARE) * sum(others.values()) or main.get(h) != r:
            continue
        rest = [q for q in members if q != p and owner[q] == g]
        if rest and any(_shared(touching, p, q) for q, o in owner.items() if o == h) \
                and apart([p], rest):
            owner[p] = h


def depths_apart(frag: np.ndarray, ground: np.ndarray, costs: SampledCosts, sigmas: float,
                 a: Sequence[int], b: Sequence[int]) -> bool:
    """Whether the plane sweep puts fragments ``a`` and ``b`` two or more depth hypotheses
    apart (``segmentation.seed_by_depth`` on their pixels and the ground beside them)."""
    both = np.isin(frag, [*a, *b])
    rows, cols = np.nonzero(both)
    height, width = frag.shape
    y0, y1 = max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, height)
    x0, x1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, width)
    crop = frag[y0:y1, x0:x1]
    mask = both[y0:y1, x0:x1]
    markers = np.where(mask, 0, 3).astype(np.int32)
    markers[np.isin(crop, a)] = 1
    markers[np.isin(crop, b)] = 2
    return seed_by_depth(markers, mask, ground[y0:y1, x0:x1], costs, (y0, x0), sigmas)


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


def landing(frag: np.ndarray, owner: Mapping[int, int],
            depth: Mapping[int, float] | np.ndarray, sweep: PlaneSweep,
            other: np.ndarray) -> Landing:
    """Where every pixel of the left retina's fragments falls in the right retina, placed
    at its group's depth (all fragments in one projection).

    Args:
        frag: Fragment labels of the left retina (0 ground).
        owner: Group (a representative fragment) of every fragment.
        depth: Depth (m, left optical axis) of every group, indexed by its representative.
        sweep: The frame's geometry (left pixel at a depth -> right pixel).
        other: Group labels of the right retina (``group_labels``).
    """
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
    on = seen > 0
    m = int(other.max()) + 1
    counts = np.bincount(lab[on] * m + seen[on], minlength=n * m).reshape(n, m)
    return Landing(rows, cols, lab, seen, np.where(inside, cu, -1), np.where(inside, cv, -1),
                    counts, np.bincount(frag.ravel(), minlength=n))


def _falls_on(land: Landing, owner: Mapping[int, int]) -> dict[int, int]:
    """The right-retina group each fragment's pixels fall on; fragments of which too few
    land on objects there, or with no group holding a clear majority, are left out."""
    counts = land.counts
    n = counts.shape[0]
    landed = counts.sum(axis=1)
    best = counts.argmax(axis=1)
    share = counts[np.arange(n), best]
    # At least half a pixel landed, so ``landed`` > 0 wherever this holds.
    good = (landed >= ON_OBJECTS * np.maximum(land.area, 1)) & (share >= MAJORITY * landed)
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
